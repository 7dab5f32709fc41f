"""The report of a recording: each artifact valid (MP4 decodable, SVG parseable, the page's
links resolving), ``objective report DIR`` re-rendering them, the plotted quantities, and the page
rendered by a headless Chromium (slow)."""
from __future__ import annotations

import io
import re
import shutil
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import imageio.v2 as imageio
import imageio.v3 as iio
import numpy as np
import pytest

from runtime.app.cli import main
from runtime.errors import ObjectiveError
from runtime.app.display import ProgressLine
from recording.report import load_recording, render_report
from recording.report.data import CommandedGoal, Recording
from recording.report import plots
from recording.report.plots import commanded_series, stall_spans
from recording.report.tree_svg import build_boxes, tree_svg

from .browser import HeadlessPage, chromium
from .test_recording import HALTED_XML, record_run

ARTIFACTS = ("joints.svg", "latency.svg", "tree.svg", "cameras.mp4", "report.html")
SVG = "{http://www.w3.org/2000/svg}"


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    code, rec = record_run(tmp_path_factory.mktemp("report"))
    assert code == 0
    return rec


class Links(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.targets: list[str] = []
        self.tags: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)
        for name, value in attrs:
            if name in ("src", "href") and value:
                self.targets.append(value)


def page_links(path: Path) -> Links:
    parser = Links()
    parser.feed(path.read_text())
    return parser


def test_every_artifact_is_written_and_valid(recording):
    for name in ARTIFACTS:
        assert (recording / name).stat().st_size > 0, name
    for name in ("joints.svg", "latency.svg", "tree.svg"):
        assert ET.parse(recording / name).getroot().tag == f"{SVG}svg", name


def svg_texts(path: Path) -> list[str]:
    return [t.text or "" for t in ET.parse(path).getroot().iter(f"{SVG}text")]


def test_joint_plot_shows_every_joint_commanded_and_measured_with_units(recording):
    loaded = load_recording(recording)
    root = ET.parse(recording / "joints.svg").getroot()
    assert int(root.get("width")) >= 1000 and int(root.get("height")) > 110 * len(loaded.joints.names)
    texts = svg_texts(recording / "joints.svg")
    assert set(loaded.joints.names) <= set(texts)
    assert {"position (rad)", "velocity (rad/s)", "time (s, runtime clock)", "measured", "commanded", "chunk seam",
            "policy request"} <= set(texts)
    lines = list(root.iter(f"{SVG}polyline"))
    measured = [p for p in lines if p.get("stroke") == plots.MEASURED_COLOR]
    assert len(measured) == 2 * len(loaded.joints.names)  # position and velocity of each joint
    assert any(p.get("stroke") == plots.COMMANDED_COLOR and p.get("stroke-dasharray") for p in lines)
    seams = [p for p in root.iter(f"{SVG}path") if p.get("stroke") == plots.SEAM_COLOR and p.get("d", "").startswith("M")]
    executed = len(loaded.of_kind("chunk_executed"))
    assert executed > 0 and all(p.get("d").count("M") == executed for p in seams[:2])  # one line per seam


def test_latency_plot_has_a_bar_per_executed_chunk_and_the_warmup(recording):
    loaded = load_recording(recording)
    root = ET.parse(recording / "latency.svg").getroot()
    bars = [r.get("fill") for r in root.iter(f"{SVG}rect") if r.get("class") == "bar"]
    assert sorted(bars) == sorted([plots.REQUEST_COLOR] + [plots.SEAM_COLOR] * len(loaded.of_kind("chunk_executed")))
    assert "chunk (0 = warmup request)" in svg_texts(recording / "latency.svg")


def test_video_has_one_frame_per_policy_request_with_the_three_views(recording):
    requests = len(load_recording(recording).requests)
    reader = imageio.get_reader(recording / "cameras.mp4")
    try:
        frames = [frame for frame in reader]
    finally:
        reader.close()
    assert len(frames) == requests == 4  # the warmup and three chunk requests
    # Three 32x32 views scaled to 240 px high, side by side; the kinematic cell's frames are flat gray.
    assert frames[0].shape == (240, 720, 3)
    assert abs(float(frames[0].mean()) - 128) < 3


def test_page_references_only_files_that_exist(recording):
    links = page_links(recording / "report.html")
    assert set(links.targets) >= {"joints.svg", "latency.svg", "tree.svg", "cameras.mp4", "run.mcap", "events.jsonl"}
    for target in links.targets:
        assert not re.match(r"^[a-z]+://", target), f"the page loads {target} from outside the recording"
        assert (recording / target).is_file(), target
    text = (recording / "report.html").read_text()
    assert "Short Policy Run: <span class=\"SUCCESS\">SUCCESS</span>" in text
    assert "<th>ExecutePolicy steps executed</th><td>60</td>" in text
    assert "video" in links.tags


def test_tree_svg_colours_each_node_by_its_final_status(recording):
    svg = (recording / "tree.svg").read_text()
    statuses = re.findall(r'<g class="node" data-status="(\w+)"><title>([^<]*)</title>', svg)
    by_name = {title.split(" [")[0]: status for status, title in statuses}
    assert by_name["ExecutePolicy"] == "SUCCESS"
    assert by_name["skipped check"] == "SKIPPED"
    assert by_name["Sequence"] == "SUCCESS"
    assert len(statuses) == 5  # guards are drawn as the node they guard


def test_report_command_renders_again_from_the_recording(recording, capsys, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(recording, copy)
    for name in ARTIFACTS:
        (copy / name).unlink()
    assert main(["report", str(copy)]) == 0
    printed = capsys.readouterr().out.split()
    assert sorted(Path(p).name for p in printed) == sorted(ARTIFACTS)
    for name in ARTIFACTS:
        assert (copy / name).stat().st_size > 0
    assert (copy / "tree.svg").read_text() == (recording / "tree.svg").read_text()


def test_report_of_a_directory_that_is_no_recording_is_bad_input(tmp_path, capsys):
    assert main(["report", str(tmp_path)]) == 2
    assert f"error: {tmp_path}: no events.jsonl (is this a directory written by `objective run --record`?)" in capsys.readouterr().err


def test_a_run_without_policy_or_robot_still_gets_a_report(tmp_path):
    code, rec = record_run(tmp_path, HALTED_XML)
    assert code == 1
    report = render_report(rec)
    assert report.errors == {} and "video" not in report.files
    page = (rec / "report.html").read_text()
    assert "no camera frames were recorded" in page and "<video" not in page
    assert 'data-status="HALTED"><title>long wait [Wait] halted: halted' in (rec / "tree.svg").read_text()
    assert 'data-status="FAILURE"><title>Timeout' in (rec / "tree.svg").read_text()
    for target in page_links(rec / "report.html").targets:
        assert (rec / target).is_file(), target


# -- the plotted quantities --------------------------------------------------------------------
def goal(sent_at: float, start: float, steps: int, value: float) -> CommandedGoal:
    times = start + 0.5 * np.arange(steps)
    return CommandedGoal("/c/joint_trajectory", sent_at, ["j"], times, np.full((steps, 1), value), np.zeros((steps, 1)))


def test_commanded_motion_switches_to_each_goal_at_its_seam():
    series = commanded_series([goal(0.0, 0.0, 5, 1.0), goal(0.8, 1.0, 3, 2.0)], "j")
    assert series is not None
    assert series.times.tolist() == [0.0, 0.5, 1.0, 1.5, 2.0]
    assert series.position.tolist() == [1.0, 1.0, 2.0, 2.0, 2.0]
    assert commanded_series([goal(0.0, 0.0, 5, 1.0)], "other") is None


def test_stall_bands_are_the_stalls_execute_policy_counted():
    def event(kind: str, time: float, **data: float) -> dict:
        return {"kind": kind, "time": time, "source": "p", "data": data}

    recording = Recording(Path("."))
    recording.events = [
        event("chunk_executed", 0.9, seam_time=1.0, stall_s=0.0),
        event("chunk_executed", 2.4, seam_time=2.5, stall_s=0.3),  # the arm left full speed at 2.2
        event("chunk_executed", 4.0, seam_time=4.2, stall_s=0.5),
        event("chunk_rolled_back", 4.1, stall_s=0.5),  # its goal came late: planned again
        event("chunk_executed", 4.3, seam_time=4.4, stall_s=0.7),
        event("policy_finished", 9.0, stall_s=1.5),  # the run ended while the arm waited
    ]
    assert stall_spans(recording) == [(2.5 - 0.3, 2.5), (4.4 - 0.7, 4.4), (9.0 - 1.5, 9.0)]


def test_tree_layout_never_overlaps_boxes_of_one_level():
    nodes = [{"id": i, "parent": 6 if i < 6 else None, "name": f"node with a long name {i}", "type": "Wait",
              "kind": "Action", "transparent": False, "location": None} for i in range(6)]
    nodes.append({"id": 6, "parent": None, "name": "root", "type": "Sequence", "kind": "Control", "transparent": False, "location": None})
    svg = tree_svg(nodes, {6: ("RUNNING", "")})
    rects = [tuple(float(v) for v in m) for m in re.findall(r'<rect x="([\d.]+)" y="([\d.]+)" width="([\d.]+)"', svg)][7:]
    leaves = sorted(r for r in rects if r[1] == max(r[1] for r in rects))
    assert len(leaves) == 6
    assert all(a[0] + a[2] <= b[0] for a, b in zip(leaves, leaves[1:]))
    root = build_boxes(nodes, {6: ("RUNNING", "")})
    assert root is not None and root.status == "RUNNING" and {c.status for c in root.children} == {"IDLE"}


def test_progress_line_shows_the_policy_run():
    class Policy:
        def __init__(self) -> None:
            self.children: list = []

        def iterate(self):
            yield self

        def run_summary(self):
            return {"execute_policy": {"chunks": 6, "steps_executed": 120, "latency_p50_s": 0.0123,
                                       "latency_max_s": 0.2, "stall_seconds": 0.5}}

    stream = io.StringIO()
    line = ProgressLine(stream)
    line.started(SimpleNamespace(root=Policy()))  # type: ignore[arg-type]
    line.show(12.3, 1230, "ExecutePolicy")
    assert stream.getvalue() == ("\rt=   12.30s  ticks=   1230  steps 120  chunks 6  latency p50/max 0.012/0.200 s  "
                                 "stalls 0.50 s  running: ExecutePolicy")


# -- in a browser ------------------------------------------------------------------------------
SCREENSHOT_DIR = Path(__file__).resolve().parents[1] / "build" / "test-output"


@pytest.mark.skipif(chromium() is None, reason="headless Chromium is not installed (apt-get install chromium)")
def test_the_page_works_in_headless_chromium(recording, tmp_path):
    """Loads without console errors, every link and source resolves, every figure (the tree SVG
    too) decodes, the video plays; the screenshot is kept in build/test-output/report.png."""
    with HeadlessPage(recording / "report.html", tmp_path / "profile") as page:
        figures = page.evaluate("Array.from(document.images).map(i => [i.getAttribute('src'), i.naturalWidth])")
        links = page.evaluate(
            "Array.from(document.querySelectorAll('[href],[src]')).map(e => e.getAttribute('href') || e.getAttribute('src'))")
        video = page.evaluate("""(async () => {
            const v = document.querySelector('video');
            v.muted = true;
            await v.play();
            await new Promise(r => setTimeout(r, 600));
            return {time: v.currentTime, width: v.videoWidth, duration: v.duration, error: v.error && v.error.code};
        })()""")
        shot = page.screenshot()
        errors = list(page.errors)
    SCREENSHOT_DIR.mkdir(parents=True, exist_ok=True)
    (SCREENSHOT_DIR / "report.png").write_bytes(shot)
    assert errors == []
    assert dict(figures) == {name: int(ET.parse(recording / name).getroot().get("width"))
                             for name in ("joints.svg", "latency.svg", "tree.svg")}
    assert all(width > 0 for _, width in figures), figures
    local = [link for link in links if "://" not in link and not link.startswith("#")]
    assert {"joints.svg", "latency.svg", "tree.svg", "cameras.mp4"} <= set(local)
    assert all((recording / link).is_file() for link in local), local
    assert video["error"] is None and video["width"] > 0 and video["duration"] > 0
    assert video["time"] > 0, "the video did not play"
    assert iio.imread(io.BytesIO(shot)).shape[1] >= 1000


def mcap_record_offsets(data: bytes) -> list[int]:
    """Where each record of an MCAP file starts: after the 8-byte magic, a record is an opcode
    byte, a little-endian 8-byte length and that many bytes."""
    offsets, at = [], 8
    while at + 9 <= len(data):
        offsets.append(at)
        at += 9 + int.from_bytes(data[at + 1: at + 9], "little")
    return offsets


@pytest.mark.parametrize("into", [1, 5, 12])
def test_a_recording_cut_anywhere_in_a_record_reads_as_partial(recording, tmp_path, into):
    """A run.mcap cut short (a full disk, a killed writer) inside a record's opcode and length
    (1, 5 bytes in) or inside its body (12) reads as a partial recording up to the last whole
    chunk, never as an error."""
    from recording.report.data import load_recording

    copy = tmp_path / "cut"
    shutil.copytree(recording, copy)
    mcap = copy / "run.mcap"
    data = mcap.read_bytes()
    offsets = mcap_record_offsets(data)
    middle = offsets[len(offsets) // 2]
    mcap.write_bytes(data[: middle + into])
    loaded = load_recording(copy)
    assert any(p.startswith("run.mcap ends early") for p in loaded.partial), loaded.partial


# -- a recording is untrusted data -----------------------------------------------------------
def hostile_recording(directory: Path, write: Any) -> Path:
    """A recording directory whose run.mcap ``write(writer)`` fills (an mcap ``Writer``)."""
    from mcap.writer import CompressionType, Writer

    directory.mkdir()
    (directory / "events.jsonl").write_text("")
    with open(directory / "run.mcap", "wb") as stream:
        writer = Writer(stream, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="test")
        write(writer)
        writer.finish()
    return directory


def test_a_schema_name_in_a_recording_never_imports_its_module(tmp_path, monkeypatch):
    """A schema naming any module (``this/msg/Zen`` printed the Zen of Python) on the topics the
    report decodes is counted by its name, never imported."""
    package = tmp_path / "path" / "planted"
    (package / "msg").mkdir(parents=True)
    (package / "__init__.py").write_text(f"open({str(tmp_path / 'imported')!r}, 'w').write('yes')\n")
    (package / "msg" / "__init__.py").write_text("JointState = String = None\n")
    monkeypatch.syspath_prepend(str(tmp_path / "path"))

    def write(writer: Any) -> None:
        for topic, name in (("/joint_states", "planted/msg/JointState"), ("/policy/request", "planted/msg/String"),
                            ("/c/joint_trajectory", "this/msg/Zen"), ("/g/_action/goal", "planted/action/GripperCommand_Goal")):
            schema = writer.register_schema(name=name, encoding="ros2msg", data=b"string data")
            channel = writer.register_channel(topic=topic, message_encoding="cdr", schema_id=schema)
            writer.add_message(channel, log_time=1, publish_time=1, data=b"\x00\x01\x00\x00\x00\x00\x00\x00")

    loaded = load_recording(hostile_recording(tmp_path / "rec", write))
    assert not (tmp_path / "imported").exists()
    assert loaded.topics["/joint_states"] == ("planted/msg/JointState", 1) and loaded.joints is None
    assert loaded.topics["/c/joint_trajectory"] == ("this/msg/Zen", 1) and loaded.goals == []


def zstd_chunk_file(path: Path, declared: int, zeros: int, piece: int = 1 << 20) -> None:
    """An MCAP file of one zstd chunk of ``zeros`` zero bytes (compressed a piece at a time, so
    the test holds no more than ``piece``) that declares ``declared`` bytes uncompressed."""
    import struct
    import zstandard

    compressor = zstandard.ZstdCompressor().compressobj()
    data = b"".join(compressor.compress(bytes(min(piece, zeros - at))) for at in range(0, zeros, piece))
    data += compressor.flush()
    name = b"zstd"
    body = struct.pack("<QQQI", 0, 0, declared, 0) + struct.pack("<I", len(name)) + name + struct.pack("<Q", len(data)) + data
    header = struct.pack("<I", 4) + b"ros2" + struct.pack("<I", 4) + b"test"
    magic = b"\x89MCAP0\r\n"
    path.write_bytes(magic + b"\x01" + struct.pack("<Q", len(header)) + header
                     + b"\x06" + struct.pack("<Q", len(body)) + body)


@pytest.mark.parametrize("declared, zeros, message", [
    (1 << 40, 1024, "declares 1099511627776 bytes uncompressed, over the 67108864 a recording's chunk may have: not read"),
    (1 << 20, 8 << 20, "decompresses to more than the 1048576 bytes it declares: not read"),
])
def test_a_compression_bomb_is_refused_before_it_is_expanded(tmp_path, capsys, declared, zeros, message):
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "events.jsonl").write_text("")
    zstd_chunk_file(rec / "run.mcap", declared, zeros)
    assert main(["report", str(rec)]) == 2
    assert f"error: {rec / 'run.mcap'}: chunk 1 {message}" in capsys.readouterr().err


def test_a_recording_expands_at_most_a_bounded_multiple_of_its_size(recording):
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    from recording.report.data import read_mcap
    from recording.report.mcap_reader import ReadLimits

    mcap = recording / "run.mcap"
    with open(mcap, "rb") as stream:
        sizes = [r.uncompressed_size for r in StreamReader(stream, emit_chunks=True).records if isinstance(r, Chunk)]
    expansion = sum(sizes) / mcap.stat().st_size
    assert len(sizes) >= 2 and 3 < expansion < 20  # the recorder's chunks expand 5 to 10 times
    read_mcap(mcap, Recording(recording), ReadLimits(expansion=20))
    tight = ReadLimits(max_chunk_bytes=max(sizes), expansion=(sum(sizes) - max(sizes)) / mcap.stat().st_size / 2)
    with pytest.raises(ObjectiveError, match=r"chunk \d+ would expand the file's chunks to more than [\d.]+ times the "
                                             r"file's size: not read \(a compression bomb, not a recording\)"):
        read_mcap(mcap, Recording(recording), tight)


def test_a_record_over_the_size_limit_is_refused_naming_its_length():
    from mcap.writer import CompressionType, Writer

    from recording.report.mcap_reader import ReadLimits, records

    buffer = io.BytesIO()
    writer = Writer(buffer, compression=CompressionType.NONE)
    writer.start()
    channel = writer.register_channel("/t", "cdr", writer.register_schema("s", "ros2msg", b"x"))
    writer.add_message(channel, 0, b"y" * 50_000, 0)
    writer.finish()
    data = buffer.getvalue()
    with pytest.raises(ObjectiveError, match=r"a record after chunk 0 is over the \d+ bytes a recording's record may "
                                             r"have \(CHUNK record has length \d+ that exceeds limit \d+\): not read"):
        list(records(io.BytesIO(data), Path("x.mcap"), len(data), ReadLimits(max_chunk_bytes=100, expansion=1.0)))


def test_a_chunk_of_anything_but_records_is_refused_at_its_first_byte(tmp_path, capsys):
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "events.jsonl").write_text("")
    zstd_chunk_file(rec / "run.mcap", 8 << 20, 8 << 20)  # 8 MiB of zeros: opcode 0, nine bytes at a time
    assert main(["report", str(rec)]) == 2
    assert "chunk 1 holds opcode 0x00 at byte 0 of 8388608: not a recording's chunk" in capsys.readouterr().err


# -- a failed run: the rejected chunk, its whole reason, the time axis ending with the run ---------
def _failed_recording() -> Recording:
    recording = Recording(Path("."))
    recording.goals = [goal(0.0, 0.0, 11, 1.0)]  # commanded until 5 s; the run stopped at 2 s
    recording.summary = {"status": "FAILURE", "sim_seconds": 2.0}
    reason = ("chunk 2 rejected: densified step 0 (t=1.270 s): joint j acceleration -25.0947 rad/s^2 exceeds the limit "
              "-5.0000 rad/s^2 (policy step 22 of the run); the arm was stopped and the goal cancelled before it moved there")
    recording.events = [
        {"kind": "chunk_requested", "time": 1.0, "source": "p", "data": {}},
        {"kind": "chunk_rejected", "time": 1.2, "source": "p",
         "data": {"reason": reason, "joints": ["j"], "times": [1.0, 1.1, 1.2], "positions": [[1.0], [1.5], [3.0]]}},
    ]
    return recording


def test_a_failed_run_s_time_axis_and_commanded_line_stop_where_the_run_ended():
    recording = _failed_recording()
    assert plots._time_span(recording, None, plots.run_end_s(recording))[1] == pytest.approx(2.02)  # 1 % padding, not 5 s
    assert commanded_series(recording.goals, "j", end_s=2.0).times.max() == 2.0


def test_the_joint_plot_draws_the_rejected_chunk(tmp_path):
    recording = _failed_recording()
    chunks = plots.rejected_chunks(recording, "j")
    assert [c.position.tolist() for c in chunks] == [[1.0, 1.5, 3.0]]
    svg = plots.joints_plot(recording, tmp_path / "joints.svg").read_text()
    assert svg.count(f'stroke="{plots.REJECTED_COLOR}"') >= 3  # position, velocity and the legend
    assert "rejected chunk" in svg


def test_the_rejection_label_is_wrapped_whole_inside_the_plot(tmp_path):
    recording = _failed_recording()
    recording.events.append({"kind": "chunk_executed", "time": 0.9, "source": "p",
                             "data": {"chunk": 1, "latency": 0.1, "seam_time": 1.0}})
    svg = ET.parse(plots.latency_plot(recording, tmp_path / "latency.svg")).getroot()
    lines = [t.text for t in svg.iter(f"{SVG}text") if t.get("fill") == plots.STALL_COLOR]
    reason = recording.of_kind("chunk_rejected")[0]["data"]["reason"]
    assert " ".join(lines) == f"rejected: {reason}"
    usable = plots.LATENCY_WIDTH_PX - 70 - 15 - 12
    assert all(len(line) * plots.CHAR_WIDTH_EM * 10 <= usable for line in lines)
