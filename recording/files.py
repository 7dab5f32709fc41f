"""The files of a recording directory (``objective run --record DIR``); see docs/recording.md."""

MCAP_FILE = "run.mcap"
EVENTS_FILE = "events.jsonl"
JOINTS_FILE, LATENCY_FILE, VIDEO_FILE, TREE_FILE, HTML_FILE = (
    "joints.svg", "latency.svg", "cameras.mp4", "tree.svg", "report.html")
FORMER_REPORT_FILES = ("joints.png", "latency.png")
"""The plots as earlier versions wrote them."""
REPORT_FILES = (JOINTS_FILE, LATENCY_FILE, VIDEO_FILE, TREE_FILE, HTML_FILE, *FORMER_REPORT_FILES)
"""Rendered by ``recording.report``; a new recording into the same directory removes the old ones."""
