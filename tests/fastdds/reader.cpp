// A ROS 2 node's view of rfhoming's sensor topics, read with eProsima Fast DDS (ROS 2's default
// middleware) and types fastddsgen made from ROS 2's message definitions (ros2_msgs.idl):
// rt/rfhoming/aoa/angle (rfhoming_msgs/AoaAngle), rt/rfhoming/tag_TAG/pose
// (geometry_msgs/PoseWithCovarianceStamped) and rt/rfhoming/tag_TAG/point (PointStamped), each with a
// best-effort reader (rclcpp's sensor-data QoS, which matches a reliable writer too). Prints one JSON
// line per sample. Loopback only, as robot.cpp.
// usage: reader DOMAIN TAG SECONDS -- ends after SECONDS or once one sample of each topic arrived.
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <thread>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
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

static std::atomic<int> angles{0}, poses{0}, points{0};

static void print_header(const std_msgs::msg::dds_::Header_& h) {
    std::printf("\"frame\": \"%s\", \"stamp\": [%d, %u]", h.frame_id().c_str(), h.stamp().sec(), h.stamp().nanosec());
}

struct AngleListener : DataReaderListener {
    void on_data_available(DataReader* reader) override {
        rfhoming_msgs::msg::dds_::AoaAngle_ a;
        SampleInfo info;
        while (reader->take_next_sample(&a, &info) == ReturnCode_t::RETCODE_OK) {
            if (!info.valid_data) continue;
            std::printf("{\"topic\": \"angle\", ");
            print_header(a.header());
            std::printf(", \"tag\": \"%s\", \"anchor\": \"%s\", \"azimuth\": %.6f, \"elevation\": %.6f, "
                        "\"board_azimuth\": %d, \"board_elevation\": %d, \"rssi\": %d, "
                        "\"reserved\": %d, \"channel\": %u, \"timestamp_ms\": %u, \"seq\": %d}\n",
                        a.instance_id().c_str(), a.anchor_id().c_str(), a.azimuth_rad(), a.elevation_rad(),
                        a.board_azimuth_deg(), a.board_elevation_deg(),
                        a.rssi1_dbm(), a.reserved(), a.channel(), a.timestamp_ms(), a.seq());
            std::fflush(stdout);
            ++angles;
        }
    }
};

struct PoseListener : DataReaderListener {
    void on_data_available(DataReader* reader) override {
        geo::PoseWithCovarianceStamped_ p;
        SampleInfo info;
        while (reader->take_next_sample(&p, &info) == ReturnCode_t::RETCODE_OK) {
            if (!info.valid_data) continue;
            const auto& pose = p.pose().pose();
            std::printf("{\"topic\": \"pose\", ");
            print_header(p.header());
            std::printf(", \"xyz\": [%.6f, %.6f, %.6f], \"orientation\": [%g, %g, %g, %g], \"covariance\": [",
                        pose.position().x(), pose.position().y(), pose.position().z(), pose.orientation().x(),
                        pose.orientation().y(), pose.orientation().z(), pose.orientation().w());
            for (int i = 0; i < 36; ++i) std::printf("%s%.9g", i ? ", " : "", p.pose().covariance()[i]);
            std::printf("]}\n");
            std::fflush(stdout);
            ++poses;
        }
    }
};

struct PointListener : DataReaderListener {
    void on_data_available(DataReader* reader) override {
        geo::PointStamped_ p;
        SampleInfo info;
        while (reader->take_next_sample(&p, &info) == ReturnCode_t::RETCODE_OK) {
            if (!info.valid_data) continue;
            std::printf("{\"topic\": \"point\", ");
            print_header(p.header());
            std::printf(", \"xyz\": [%.6f, %.6f, %.6f]}\n", p.point().x(), p.point().y(), p.point().z());
            std::fflush(stdout);
            ++points;
        }
    }
};

int main(int argc, char** argv) {
    if (argc != 4) { std::fprintf(stderr, "usage: reader DOMAIN TAG SECONDS\n"); return 2; }
    int domain = std::atoi(argv[1]);
    std::string tag = argv[2];
    double seconds = std::atof(argv[3]);

    DomainParticipantQos pqos;
    pqos.transport().use_builtin_transports = false;
    auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
    udp->interfaceWhiteList.push_back("127.0.0.1");
    pqos.transport().user_transports.push_back(udp);
    for (int pid = 0; pid < 32; ++pid) {
        Locator_t p;
        IPLocator::setIPv4(p, 127, 0, 0, 1);
        p.port = 7400 + 250 * domain + 10 + 2 * pid;
        pqos.wire_protocol().builtin.initialPeersList.push_back(p);
    }
    DomainParticipant* dp = DomainParticipantFactory::get_instance()->create_participant(domain, pqos);
    if (!dp) { std::fprintf(stderr, "no participant\n"); return 1; }
    TypeSupport angle_type(new rfhoming_msgs::msg::dds_::AoaAngle_PubSubType());
    TypeSupport pose_type(new geo::PoseWithCovarianceStamped_PubSubType());
    TypeSupport point_type(new geo::PointStamped_PubSubType());
    angle_type.register_type(dp);
    pose_type.register_type(dp);
    point_type.register_type(dp);
    Subscriber* sub = dp->create_subscriber(SUBSCRIBER_QOS_DEFAULT);
    DataReaderQos qos = DATAREADER_QOS_DEFAULT;  // rclcpp sensor data: best effort, volatile, keep last 5
    qos.reliability().kind = BEST_EFFORT_RELIABILITY_QOS;
    qos.durability().kind = VOLATILE_DURABILITY_QOS;
    qos.history().kind = KEEP_LAST_HISTORY_QOS;
    qos.history().depth = 5;
    AngleListener angle_listener;
    PoseListener pose_listener;
    PointListener point_listener;
    std::string prefix = "rt/rfhoming/tag_" + tag;
    DataReader* r1 = sub->create_datareader(
        dp->create_topic("rt/rfhoming/aoa/angle", angle_type.get_type_name(), TOPIC_QOS_DEFAULT), qos, &angle_listener);
    DataReader* r2 = sub->create_datareader(
        dp->create_topic(prefix + "/pose", pose_type.get_type_name(), TOPIC_QOS_DEFAULT), qos, &pose_listener);
    DataReader* r3 = sub->create_datareader(
        dp->create_topic(prefix + "/point", point_type.get_type_name(), TOPIC_QOS_DEFAULT), qos, &point_listener);
    if (!r1 || !r2 || !r3) { std::fprintf(stderr, "no entities\n"); return 1; }
    std::printf("{\"ready\": %d}\n", domain);
    std::fflush(stdout);
    auto start = std::chrono::steady_clock::now();
    while (!(angles > 0 && poses > 0 && points > 0) &&
           std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() < seconds)
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    std::printf("{\"done\": [%d, %d, %d]}\n", angles.load(), poses.load(), points.load());
    std::fflush(stdout);
    dp->delete_contained_entities();
    DomainParticipantFactory::get_instance()->delete_participant(dp);
    return 0;
}
