"""A policy run's start-up and warmup: what is waited for, the hints when something is missing,
and how the warmup's call fails.

The start-up waits up to ``STARTUP_WAIT_S`` for the policy service, the controller action, the
gripper action, reliable joint states and a reading on the wrench topic, and then for a frame on
every camera (looked at once the rest is there: a read may render a frame); what is still missing
then is an ERROR naming it. The warmup is one request with ``new_episode=true`` whose chunk is
thrown away: its round trip is the first of the latency estimate.
"""
from __future__ import annotations

from typing import Any, Sequence

from runtime.io.bus import Bus, ServedListing, capability

from . import config as cfg
from .failure import Failure, FailureKind
from .links import SessionLinks

STARTUP_WAIT_S = 5.0


def missing_links(links: SessionLinks, config: cfg.PolicyRunConfig, bus: Bus) -> list[str]:
    """What is not there yet besides the cameras, each with what to do about it."""
    missing = []
    if not links.policy.ready():
        missing.append(f"policy service '{config.policy_service_name}' ({policy_hint(bus)})")
    if not links.controller.ready():  # a name served with another type is an ERROR here
        missing.append(f"controller action '{config.controller_action_name}'")
    if links.gripper is not None and not links.gripper.ready():
        missing.append(f"gripper action '{config.gripper_command_action_name}'")
    if links.joint_states.latest is None:
        missing.append(f"joint states on '{config.joint_states_topic}' (the publisher must use reliable QoS)")
    if links.wrench is not None and not links.wrench.has_reading:
        missing.append(f"a reading on wrench topic '{config.wrench_topic}' (is force_torque_sensor_broadcaster active?)")
    return missing


def missing_frames(image_topics: Sequence[str], frames: Sequence[Any]) -> list[str]:
    """The camera topics with no frame yet (``frames``: the newest of each, None when none)."""
    return [f"a frame on camera topic '{topic}' (subscribed best-effort, so a reliable or a "
            "best-effort publisher matches; is the camera driver publishing there?)"
            for topic, frame in zip(image_topics, frames) if frame is None]


def not_available(missing: Sequence[str]) -> str:
    """The ERROR of a start-up that timed out with ``missing`` still missing."""
    return f"not available after {STARTUP_WAIT_S:.0f} s: " + "; ".join(missing)


def policy_hint(bus: Bus) -> str:
    """What to do about a missing policy service, in the mode the run on ``bus`` is in."""
    listing = capability(bus, ServedListing)
    if listing is None:  # a ROS 2 graph: the adapter serves the policy
        return "start the adapter (`objective adapter`) before running the Objective"
    names = ", ".join(sorted(listing.served())) or "none"
    return f"in this run the world serves the policy chosen with --policy; services here: {names}"


def warmup_timed_out(config: cfg.PolicyRunConfig) -> Failure:
    return Failure(
        FailureKind.POLICY_TIMEOUT,
        f"warming up the policy service '{config.policy_service_name}' timed out after {config.policy_call_timeout:g} s "
        "(raise policy_call_timeout, or make the server finish its own warmup before it reports ready)")


def warmup_failed(config: cfg.PolicyRunConfig, error: Exception) -> Failure:
    """A transport failure of the warmup call."""
    return Failure(FailureKind.POLICY_ERROR, f"warming up the policy service '{config.policy_service_name}' failed: {error}")
