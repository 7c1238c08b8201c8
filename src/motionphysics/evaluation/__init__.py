"""Evaluation of run directories: ``eval`` (every metric of one run, from its files
alone) and ``compare`` (several runs side by side in the layout of the paper's Table 2).

Sits above ``metrics`` (the metric functions) and ``io`` (run-directory files); nothing
below the commands imports it.
"""
