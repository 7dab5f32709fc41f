"""ResetSim: put the simulated world back in its initial state with a new seeded layout.

A world-level node: it calls ``context.world.reset(seed)`` directly, because a reset is not
something a real robot offers on the bus. Against a run without a simulated world it fails
with a reason instead of pretending.
"""
from __future__ import annotations

from runtime.behavior import Behavior, Status
from runtime.ports import UINT32_MAX, InputPort, PortType, Range


class ResetSim(Behavior):
    """Reset the simulated world to a seeded layout, then give it one tick to publish it.

    The reset happens in the first tick; the node answers SUCCESS in the next one, after the
    runner has stepped the world and delivered its messages, so the nodes that follow read the
    new joint states and cube poses, never the ones from before the reset.
    """

    needs_world = True
    description = "Reset the simulated world (robot at its start, cubes in the layout drawn from seed)."
    ports = (InputPort("seed", PortType.UINT, 0, "Seed of the new cube layout.", valid=Range(0, UINT32_MAX)),)

    def initialise(self) -> None:
        self.reset_done = False

    def update(self) -> Status:
        if self.reset_done:
            self.feedback_message = f"world reset with seed {self.get_input('seed')}"
            return Status.SUCCESS
        world = self.context.world
        if world is None:
            return self.fail("this run hosts no simulated world to reset (ResetSim works only against a simulated cell)")
        seed = self.get_input("seed")
        try:
            world.reset(seed)
        except ValueError as err:
            return self.fail(f"the world refused the reset with seed {seed}: {err}")
        self.reset_done = True
        return Status.RUNNING


NODES = (ResetSim,)
