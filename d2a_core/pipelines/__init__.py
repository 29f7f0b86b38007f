"""What the subcommands do, above the simulator and agents: make-track, and later training and evaluation."""
