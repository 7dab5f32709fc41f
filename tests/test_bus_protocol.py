"""Every bus provides all of ``runtime.io.bus.Bus``, with the protocol's parameters, so callers
use it without probing; what only some buses can do is found with ``capability``."""
from __future__ import annotations

import inspect

import pytest

from recording.bus import RecordingBus
from recording.mcap_writer import McapRos2Writer
from runtime.io.bus import (
    Bus,
    BusWrapper,
    InProcessBus,
    InterruptibleWaits,
    RecordsTopics,
    ServedListing,
    SimulatedLatency,
    capability,
)
from runtime.io.clock import SimClock
from runtime.io.ros.bus import RosBus
from runtime.io.ros.run import HostingBus

pytestmark = pytest.mark.ros  # RosBus and HostingBus import rclpy

BUSES = [InProcessBus, RosBus, HostingBus, RecordingBus]


def members(cls: type) -> dict[str, object]:
    """The public names a class declares (its own and its bases'): attributes, methods and
    annotated fields, each with what the class holds (None for a field only annotated)."""
    found: dict[str, object] = {}
    for klass in reversed(cls.__mro__):
        if klass is object:
            continue
        found.update(dict.fromkeys(vars(klass).get("__annotations__", {})))
        found.update(vars(klass))
    return {name: value for name, value in found.items() if not name.startswith("_")}


def parameters(function: object) -> list[tuple[str, object]]:
    """A method's parameters after ``self``: name and default."""
    signature = inspect.signature(function)  # type: ignore[arg-type]
    return [(p.name, p.default) for p in list(signature.parameters.values())[1:]]


def test_the_protocol_declares_methods_and_fields():
    declared = members(Bus)
    assert {"clock", "produces_on_read", "serves", "create_subscription", "destroy_subscription",
            "create_lazy_publisher", "spin_once", "close"} <= set(declared)


@pytest.mark.parametrize("bus_class", BUSES, ids=lambda cls: cls.__name__)
def test_every_bus_provides_every_member_of_the_protocol(bus_class):
    provided = members(bus_class)
    missing = sorted(set(members(Bus)) - set(provided))
    assert not missing, f"{bus_class.__name__} lacks {missing}"
    for name, declared in members(Bus).items():
        if not callable(declared):
            continue
        method = provided[name]
        assert callable(method), f"{bus_class.__name__}.{name} is not a method"
        assert parameters(method) == parameters(declared), f"{bus_class.__name__}.{name}"


@pytest.mark.parametrize("protocol", [ServedListing, SimulatedLatency, InterruptibleWaits, RecordsTopics, BusWrapper],
                         ids=lambda protocol: protocol.__name__)
def test_a_bus_that_has_a_capability_has_it_with_the_protocols_parameters(protocol):
    for bus_class in BUSES:
        provided = members(bus_class)
        methods = {name: declared for name, declared in members(protocol).items() if callable(declared)}
        if all(name in provided for name in members(protocol)):
            for name, declared in methods.items():
                assert parameters(provided[name]) == parameters(declared), f"{bus_class.__name__}.{name}"


def test_capabilities_are_found_on_the_bus_or_the_bus_it_wraps(tmp_path):
    inner = InProcessBus(SimClock())
    writer = McapRos2Writer(tmp_path / "r.mcap")
    recording = RecordingBus(inner, writer)
    try:
        for bus in (inner, recording):
            assert isinstance(bus, Bus)
            for kind in (ServedListing, SimulatedLatency, InterruptibleWaits):
                assert capability(bus, kind) is inner
        assert capability(recording, RecordsTopics) is recording
        assert capability(inner, RecordsTopics) is None
        assert not isinstance(recording, SimulatedLatency)  # the recording bus itself only forwards the Bus
    finally:
        writer.close()
        recording.close()
