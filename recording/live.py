"""``LiveView``: the topics a recording holds, served live to Foxglove (``objective run --live``).

A Foxglove WebSocket server (the ``foxglove-sdk`` package) with one channel per topic, carrying
the same CDR bytes and ``ros2msg`` schemas as ``run.mcap`` (so Foxglove shows the same panels
for a live run and its recording). Messages are logged with the recording's log times. Topics
offered ``transient_local`` (the robot's and the scene's markers, sent once or on change) are
latched: a client that subscribes later gets their last message at once. The server listens on
loopback unless told otherwise, and stops when the run ends.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from runtime.errors import ObjectiveError
from .mcap_writer import OfferedQos, cdr_bytes, message_type, to_nanoseconds
from .schema import message_definition, type_name

DEFAULT_PORT = 8765


@dataclass(frozen=True)
class LiveOptions:
    port: int = DEFAULT_PORT
    """0 picks a free port."""
    host: str = "127.0.0.1"


class LiveView:
    """A running Foxglove WebSocket server fed by the recorder (see the module doc)."""

    def __init__(self, options: LiveOptions, clock_origin_ns: int) -> None:
        import foxglove

        self._foxglove = foxglove
        self.clock_origin_ns = clock_origin_ns
        self.qos: dict[str, OfferedQos] = {}
        self._context = foxglove.Context()
        self._channels: dict[str, Any] = {}
        self._latched: dict[str, tuple[bytes, int]] = {}
        try:
            self.server = foxglove.start_server(name="objective-runtime", host=options.host, port=options.port,
                                                context=self._context, server_listener=_latch(self))
        except Exception as err:  # the SDK raises its own error types for bind failures
            raise ObjectiveError(f"--live: cannot serve on {options.host}:{options.port} ({err})") from None
        self.url = f"ws://{options.host}:{self.server.port}"
        self.closed = False

    def _channel(self, topic: str, msg_class: type) -> Any:
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._foxglove.Schema(name=type_name(msg_class), encoding="ros2msg",
                                           data=message_definition(msg_class).encode())
            metadata = {"offered_qos_profiles": self.qos.get(topic, OfferedQos()).yaml()}
            channel = self._foxglove.Channel(topic, schema=schema, message_encoding="cdr", context=self._context,
                                             metadata=metadata)
            self._channels[topic] = channel
        return channel

    def write(self, topic: str, msg: Any, seconds: float) -> None:
        if self.closed:
            return
        channel = self._channel(topic, message_type(msg))
        log_time = self.clock_origin_ns + to_nanoseconds(seconds)
        if self.qos.get(topic, OfferedQos()).transient_local:
            data = cdr_bytes(msg)
            self._latched[topic] = (data, log_time)
            channel.log(data, log_time=log_time)
        elif channel.has_sinks():  # serialize only while someone is connected
            channel.log(cdr_bytes(msg), log_time=log_time)

    def resend_latched(self, topic: str) -> None:
        latched = self._latched.get(topic)
        channel = self._channels.get(topic)
        if latched is not None and channel is not None:
            channel.log(latched[0], log_time=latched[1])

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.server.stop()


def _latch(view: LiveView) -> Any:
    """A server listener: a new subscriber to a latched topic gets its last message."""
    from foxglove.websocket import ServerListener

    class Latch(ServerListener):
        def on_subscribe(self, client: Any, channel: Any) -> None:
            view.resend_latched(channel.topic)

    return Latch()
