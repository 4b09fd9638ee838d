"""Dataset readers and writers: CAD-60, UTKinect, LSPET, rosbag2 files (the renderer: `synth`).

Nothing in this package imports rclpy or a message package (a test checks it); bags are read and
written with the pure-Python rosbags library.
"""
