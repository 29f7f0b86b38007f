"""Training runs: the human population (FCP) and, later, the assistant."""
