#!/usr/bin/env python
"""Regenerate the figures of the paper's Section IV.

    python experiments/reproduce_paper.py --out results/paper [--quick]

A thin wrapper of :func:`vnhc_gym.paper.main` (the same as ``vnhc-gym reproduce``).
"""

import sys

from vnhc_gym.paper import main

if __name__ == "__main__":
    sys.exit(main())
