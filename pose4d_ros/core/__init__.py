"""Algorithms of the tracker: numpy, numba, OpenCV and scikit-image only.

Nothing in this package imports rclpy, a message package or rosbags (a test checks it).
"""
