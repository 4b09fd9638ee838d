"""The node graph in processes of their own, as `ros2 run` starts them (`run`)."""
