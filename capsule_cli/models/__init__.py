"""Pure physical models: numpy in, numpy out, SI units; one module per model family.

Each function's docstring cites its source (seed file and equation); parameter
sets from the papers live in ``configs/params/`` with their citations.
"""
