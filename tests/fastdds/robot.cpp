// A ROS 2 robot played with eProsima Fast DDS (ROS 2 Humble's and Jazzy's default middleware):
// publishes rt/odom (nav_msgs/Odometry, reliable as rclcpp's default QoS) at 50 Hz and rt/scan
// (sensor_msgs/LaserScan, best effort as rclcpp's sensor-data QoS) at 10 Hz, and reads rt/cmd_vel
// (geometry_msgs/Twist) with a *reliable* reader, which matches only a reliable writer. Prints
// one JSON line per event. Loopback only: UDPv4 on 127.0.0.1, unicast initial peer 127.0.0.1.
// usage: robot DOMAIN SECONDS COMMANDS -- ends after SECONDS or once COMMANDS commands arrived.
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>
#include <thread>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>

#include "ros2_msgsPubSubTypes.h"

using namespace eprosima::fastdds::dds;
using eprosima::fastrtps::rtps::IPLocator;
using eprosima::fastrtps::rtps::Locator_t;
namespace geo = geometry_msgs::msg::dds_;

static std::atomic<int> commands{0};

struct CmdListener : DataReaderListener {
    void on_subscription_matched(DataReader* reader, const SubscriptionMatchedStatus& status) override {
        if (status.current_count_change > 0)
            std::printf("{\"matched\": \"%s\", \"type\": \"%s\"}\n", reader->get_topicdescription()->get_name().c_str(),
                        reader->get_topicdescription()->get_type_name().c_str());
        std::fflush(stdout);
    }
    void on_data_available(DataReader* reader) override {
        geo::Twist_ twist;
        SampleInfo info;
        while (reader->take_next_sample(&twist, &info) == ReturnCode_t::RETCODE_OK) {
            if (!info.valid_data) continue;
            std::printf("{\"cmd\": [%.6f, %.6f, %.6f, %.6f, %.6f, %.6f]}\n", twist.linear().x(), twist.linear().y(),
                        twist.linear().z(), twist.angular().x(), twist.angular().y(), twist.angular().z());
            std::fflush(stdout);
            ++commands;
        }
    }
};

int main(int argc, char** argv) {
    if (argc != 4) { std::fprintf(stderr, "usage: robot DOMAIN SECONDS COMMANDS\n"); return 2; }
    int domain = std::atoi(argv[1]);
    double seconds = std::atof(argv[2]);
    int wanted = std::atoi(argv[3]);

    DomainParticipantQos pqos;
    pqos.transport().use_builtin_transports = false;
    auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
    udp->interfaceWhiteList.push_back("127.0.0.1");
    pqos.transport().user_transports.push_back(udp);
    for (int pid = 0; pid < 32; ++pid) {  // the unicast discovery port of each participant index
        Locator_t p;
        IPLocator::setIPv4(p, 127, 0, 0, 1);
        p.port = 7400 + 250 * domain + 10 + 2 * pid;
        pqos.wire_protocol().builtin.initialPeersList.push_back(p);
    }
    DomainParticipant* dp = DomainParticipantFactory::get_instance()->create_participant(domain, pqos);
    if (!dp) { std::fprintf(stderr, "no participant\n"); return 1; }

    TypeSupport odom_type(new nav_msgs::msg::dds_::Odometry_PubSubType());
    TypeSupport scan_type(new sensor_msgs::msg::dds_::LaserScan_PubSubType());
    TypeSupport twist_type(new geo::Twist_PubSubType());
    odom_type.register_type(dp);
    scan_type.register_type(dp);
    twist_type.register_type(dp);
    Topic* odom_topic = dp->create_topic("rt/odom", odom_type.get_type_name(), TOPIC_QOS_DEFAULT);
    Topic* scan_topic = dp->create_topic("rt/scan", scan_type.get_type_name(), TOPIC_QOS_DEFAULT);
    Topic* cmd_topic = dp->create_topic("rt/cmd_vel", twist_type.get_type_name(), TOPIC_QOS_DEFAULT);

    Publisher* pub = dp->create_publisher(PUBLISHER_QOS_DEFAULT);
    DataWriterQos odom_qos = DATAWRITER_QOS_DEFAULT;  // rclcpp default: reliable, volatile, keep last 10
    odom_qos.reliability().kind = RELIABLE_RELIABILITY_QOS;
    odom_qos.durability().kind = VOLATILE_DURABILITY_QOS;
    odom_qos.history().kind = KEEP_LAST_HISTORY_QOS;
    odom_qos.history().depth = 10;
    DataWriterQos scan_qos = odom_qos;  // rclcpp sensor data: best effort, keep last 5
    scan_qos.reliability().kind = BEST_EFFORT_RELIABILITY_QOS;
    scan_qos.history().depth = 5;
    DataWriter* odom_writer = pub->create_datawriter(odom_topic, odom_qos);
    DataWriter* scan_writer = pub->create_datawriter(scan_topic, scan_qos);

    Subscriber* sub = dp->create_subscriber(SUBSCRIBER_QOS_DEFAULT);
    DataReaderQos cmd_qos = DATAREADER_QOS_DEFAULT;
    cmd_qos.reliability().kind = RELIABLE_RELIABILITY_QOS;
    cmd_qos.durability().kind = VOLATILE_DURABILITY_QOS;
    cmd_qos.history().kind = KEEP_LAST_HISTORY_QOS;
    cmd_qos.history().depth = 10;
    CmdListener listener;
    DataReader* cmd_reader = sub->create_datareader(cmd_topic, cmd_qos, &listener);
    if (!odom_writer || !scan_writer || !cmd_reader) { std::fprintf(stderr, "no entities\n"); return 1; }
    std::printf("{\"ready\": %d}\n", domain);
    std::fflush(stdout);

    auto start = std::chrono::steady_clock::now();
    for (int k = 1;; ++k) {
        double t = k * 0.02;
        nav_msgs::msg::dds_::Odometry_ odom;
        odom.header().stamp().sec(static_cast<int32_t>(t));
        odom.header().stamp().nanosec(static_cast<uint32_t>(std::lround((t - std::floor(t)) * 1e9)));
        odom.header().frame_id("odom");
        odom.child_frame_id("base_link");
        odom.pose().pose().position().x(1.25);
        odom.pose().pose().position().y(-0.5);
        odom.pose().pose().orientation().z(std::sin(0.25));
        odom.pose().pose().orientation().w(std::cos(0.25));
        odom.twist().twist().linear().x(0.1);
        odom.twist().twist().angular().z(-0.05);
        odom_writer->write(&odom);
        if (k % 5 == 0) {
            sensor_msgs::msg::dds_::LaserScan_ scan;
            scan.header() = odom.header();
            scan.header().frame_id("laser");
            scan.angle_min(-0.5f); scan.angle_max(0.5f); scan.angle_increment(0.5f);
            scan.range_min(0.1f); scan.range_max(10.0f);
            scan.ranges({1.5f, std::numeric_limits<float>::infinity(), 3.0f});
            scan_writer->write(&scan);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
        double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        if (commands >= wanted || elapsed > seconds) break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    std::printf("{\"done\": %d}\n", commands.load());
    std::fflush(stdout);
    dp->delete_contained_entities();
    DomainParticipantFactory::get_instance()->delete_participant(dp);
    return 0;
}
