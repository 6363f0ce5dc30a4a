"""Logs for the robotics tool chain: MCAP files of ROS 2 messages (rosbags, Foxglove, ros2 bag).

Needs the ``ros`` extra (``pip install 'rfhoming[ros]'``): the mcap writer and rosbags' type store.
"""
