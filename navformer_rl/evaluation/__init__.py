"""Evaluation as in paper §VII: measures (SR, SPL eq. 12, CR), fixed episode sets, the harness, reports.

Import from the submodules (``measures``, ``episodes``, ``harness``, ``report``, ``cli``; the harness's
parts: ``policy_spec``, ``runner``); this package imports nothing heavy by itself. See ``docs/evaluation.md``.
"""
