"""What the offline jobs share that is neither algorithm nor command: progress and log lines
(`progress`), the machine and commit a result was made on (`machine`)."""
