"""What evaluations and benchmarks write down: figures, the machine they ran on, JSON reports."""
