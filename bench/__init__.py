"""Benchmarks of tensegrity_sim: work-precision against references and MuJoCo, scale, hard cases.

Not part of the installed package. ``python3 bench/run_all.py`` regenerates everything under
``bench/results/``; the tests import the reference solutions and the MuJoCo model builder from here.
"""
