"""Evaluation as in paper §VII: measures (SR, SPL eq. 12, CR), fixed episode sets, the harness, reports.

Import from the submodules (``measures``, ``episodes``, ``harness``, ``report``, ``cli``); this package
imports nothing heavy by itself. See ``docs/evaluation.md``.
"""
