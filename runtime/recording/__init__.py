"""Recording a run: ``Recorder`` (run.mcap + events.jsonl) and the ``RecordingBus`` proxy it installs."""
from .bus import RecordingBus
from .mcap_writer import McapRos2Writer
from .recorder import EVENTS_FILE, MCAP_FILE, Recorder

__all__ = ["EVENTS_FILE", "MCAP_FILE", "McapRos2Writer", "Recorder", "RecordingBus"]
