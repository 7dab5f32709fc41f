"""``metadata.yaml``: what ``ros2 bag record`` writes beside its ``.mcap`` files.

With it, the recording directory is a rosbag2 bag: ``ros2 bag info DIR`` and ``ros2 bag play DIR``
(MCAP storage plugin) read it as they read one of their own (Jazzy's format, version 9). It is
written when the recording stops; a recording cut short by a crash has none (``ros2 bag reindex``
rebuilds it from the MCAP file).
"""
from __future__ import annotations

from typing import Any

import yaml

BAG_METADATA_FILE = "metadata.yaml"
ROS_DISTRO = "jazzy"


def bag_metadata(relative_path: str, topics: dict[str, tuple[str, Any]], counts: dict[str, int],
                 first_ns: int | None, last_ns: int | None) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of one MCAP file (``topics``: name -> (type, OfferedQos))."""
    start = first_ns or 0
    duration = (last_ns - first_ns) if first_ns is not None and last_ns is not None else 0
    total = sum(counts.values())
    return {"rosbag2_bagfile_information": {
        "version": 9,
        "storage_identifier": "mcap",
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": total,
        "topics_with_message_count": [
            {"topic_metadata": {"name": name, "type": type_, "serialization_format": "cdr",
                                "offered_qos_profiles": [qos.profile()], "type_description_hash": ""},
             "message_count": counts.get(name, 0)}
            for name, (type_, qos) in topics.items()],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [relative_path],
        "files": [{"path": relative_path, "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": duration}, "message_count": total}],
        "custom_data": {},
        "ros_distro": ROS_DISTRO,
    }}


def bag_metadata_yaml(*args: Any) -> str:
    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
    return yaml.dump(bag_metadata(*args), Dumper=dumper, sort_keys=False)
