"""Benchmarks of ros_margcal, one module per area; each has ``main(argv) -> int`` and a ``--quick`` flag."""
