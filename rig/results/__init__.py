"""What a run tells: its result (``result``: ``result.json`` as a typed object), the verdicts
of its criteria (``verdict``), the report (``report``: ``report.md``), the Rerun recording
(``recording``) and its viewers (``webview``, ``browser``), the pictures (``figures``) and
JUnit XML for CI (``junit``).
"""
