"""Every stage a step: paths in, paths out, the result also returned in memory.

Steps sit above the algorithm layers (``core -> io -> geometry -> poses | track -> eval ->
synth -> steps -> cli``); the command line is a thin shell over them. Importing this package
imports no heavy dependency: each step imports its algorithms when it runs.
"""
