#!/usr/bin/env python3
"""Bake benchmark: the shared models and the generated ~650k-triangle CAD part.

    .venv/bin/python examples/bench_bake.py                    # same as `hbake bench`
    .venv/bin/python examples/bench_bake.py --repeat 3 --json out/bench_bake.json

Thin wrapper over hbake.lab.bench (see its docstring for what is measured and how).
"""
from hbake.cli.lab import bench_command

if __name__ == "__main__":
    bench_command(prog_name="bench_bake.py")
