"""rclpy nodes: thin adapters from messages to core functions and back."""
