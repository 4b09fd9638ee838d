"""The `pose4d` command: offline tools to make data, train, evaluate, benchmark and demo."""
