"""Imported by a fork server in tests/nodes/test_forkserver.py: joins the domain as it is
imported (what a server must never do before it forks), so that its participant's threads
exist when the server is asked to fork."""

import rclpy

rclpy.init()
NODE = rclpy.create_node("fork_dds")
