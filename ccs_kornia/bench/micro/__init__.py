"""Micro-benchmarks of single stages (the network, the organiser, the renderer, the solver), each run as
``python -m ccs_kornia.bench.micro.<name>``; the product-level benchmarks are the sections of :mod:`ccs_kornia.bench`.
"""
