"""MoveIt Pro's vector and pose-building nodes: make a PoseStamped, collect values in a vector,
read one back, and run a child once per element (``ForEach``).

MoveIt Pro registers its vector nodes once per element type (``PushBackVector`` of poses, of
doubles...); here one node takes any element type, and a vector on the blackboard is a Python
list. A node never changes a list in place: ``PushBackVector`` writes a new list, so a vector
another node still holds is left as it was.
"""
from __future__ import annotations

from typing import Any, ClassVar

from geometry_msgs.msg import PoseStamped

from runtime.tree.behavior import Behavior, Status
from runtime.tree.controls import COMPLETED, DecoratorNode, TickGenerator, halt_child
from runtime.tree.ports import InputPort, OutputPort, PortType, Range
from runtime.io.timestamps import time_msg


def pose_stamped(frame_id: str, position_xyz: list[float], orientation_xyzw: list[float], stamp_s: float) -> PoseStamped:
    """A PoseStamped from MoveIt Pro's port spelling; ValueError naming the port that is wrong.

    The quaternion is normalised (MoveIt Pro's Objectives write ``0.707;0.707;0;0``).
    """
    if len(position_xyz) != 3:
        raise ValueError(f"position_xyz needs 3 values (x;y;z), got {len(position_xyz)}")
    if len(orientation_xyzw) != 4:
        raise ValueError(f"orientation_xyzw needs 4 values (x;y;z;w), got {len(orientation_xyzw)}")
    norm = sum(v * v for v in orientation_xyzw) ** 0.5
    if not norm > 1e-9:
        raise ValueError(f"orientation_xyzw {list(orientation_xyzw)} is not a rotation (zero length)")
    msg = PoseStamped()
    msg.header.frame_id = frame_id
    msg.header.stamp = time_msg(stamp_s)
    p, o = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position_xyz)
    o.x, o.y, o.z, o.w = (float(v) / norm for v in orientation_xyzw)
    return msg


class CreatePoseStamped(Behavior):
    """MoveIt Pro's CreatePoseStamped: a pose from literal numbers, in a named frame."""

    description: ClassVar[str] = "Create a geometry_msgs/PoseStamped from a frame name, a position and a quaternion."
    ports = (
        InputPort("reference_frame", PortType.STRING, "world", "Frame the pose is expressed in."),
        InputPort("position_xyz", PortType.FLOAT_LIST, "0;0;0", "Position x;y;z (m).", valid=Range(-100, 100, "m")),
        InputPort("orientation_xyzw", PortType.FLOAT_LIST, "0;0;0;1", "Orientation quaternion x;y;z;w (normalised).", valid=Range(-1000, 1000)),
        OutputPort("pose_stamped", PortType.POSE_STAMPED, "The pose.", default="{pose_stamped}"),
    )

    def update(self) -> Status:
        try:
            pose = pose_stamped(
                self.get_input("reference_frame"),
                self.get_input("position_xyz"),
                self.get_input("orientation_xyzw"),
                self.context.clock.now(),
            )
        except ValueError as err:
            return self.fail(str(err))
        self.set_output("pose_stamped", pose)
        return Status.SUCCESS


class ResetVector(Behavior):
    """MoveIt Pro's ResetVector: an empty vector on the blackboard."""

    description: ClassVar[str] = "Write an empty vector (of any element type) to the blackboard."
    ports = (OutputPort("vector", PortType.ANY_LIST, "The entry to empty."),)

    def update(self) -> Status:
        self.set_output("vector", [])
        return Status.SUCCESS


class ResetPoseStampedVector(ResetVector):
    """MoveIt Pro's ResetPoseStampedVector: an empty vector of poses."""

    description: ClassVar[str] = "Write an empty std::vector<geometry_msgs::msg::PoseStamped> to the blackboard."
    ports = (OutputPort("vector", PortType.POSE_STAMPED_LIST, "The entry to empty."),)


class PushBackVector(Behavior):
    """MoveIt Pro's PushBackVector: append one element to a vector."""

    description: ClassVar[str] = (
        "Append element to input_vector and write the result to output_vector (a new list; "
        "usually the same entry: input_vector=\"{v}\" output_vector=\"{v}\")."
    )
    ports = (
        InputPort("input_vector", PortType.ANY_LIST, "", "The vector to extend (empty or unset: a new vector)."),
        InputPort("element", PortType.ANY, description="The element to append, e.g. {pose}."),
        OutputPort("output_vector", PortType.ANY_LIST, "The vector with the element appended."),
    )

    def update(self) -> Status:
        vector = self.get_input("input_vector")
        element = self.get_input("element")
        if vector and type(vector[0]) is not type(element):
            return self.fail(
                f"element is a {type(element).__name__} but input_vector holds {type(vector[0]).__name__} elements"
            )
        self.set_output("output_vector", [*vector, element])
        return Status.SUCCESS


def element_at(vector: list[Any], index: int) -> Any:
    """``vector[index]``; IndexError that gives the size when ``index`` is outside it."""
    if not 0 <= index < len(vector):
        raise IndexError(f"index {index} is outside the vector (size {len(vector)})")
    return vector[index]


class GetElementOfVector(Behavior):
    """MoveIt Pro's GetElementOfVector: one element, by its index from 0."""

    description: ClassVar[str] = "Write the element at index (from 0) of vector_in; fails when the index is outside it."
    ports = (
        InputPort("vector_in", PortType.ANY_LIST, description="The vector to read."),
        InputPort("index", PortType.UINT, 0, "Index of the element, from 0.", valid=Range(0, 1_000_000)),
        OutputPort("element", PortType.ANY, "The element."),
    )

    def update(self) -> Status:
        try:
            element = element_at(self.get_input("vector_in"), self.get_input("index"))
        except IndexError as err:
            return self.fail(str(err))
        self.set_output("element", element)
        return Status.SUCCESS


class GetSizeOfVector(Behavior):
    """MoveIt Pro's GetSizeOfVector: how many elements a vector holds."""

    description: ClassVar[str] = "Write the number of elements of vector_in."
    ports = (
        InputPort("vector_in", PortType.ANY_LIST, description="The vector to measure."),
        OutputPort("vector_size", PortType.UINT, "Its number of elements."),
    )

    def update(self) -> Status:
        self.set_output("vector_size", len(self.get_input("vector_in")))
        return Status.SUCCESS


class ForEach(DecoratorNode):
    """MoveIt Pro's ForEach: tick the child once per element of a vector.

    Before each run of the child, ``out`` is set to the next element and ``index`` to its
    position. The vector is read when the loop starts, so the child may rebuild it. A child
    that finishes in the tick it started in hands over to the next element at the next tick,
    as BT.CPP's Repeat does; a RUNNING child keeps its element until it finishes.
    """

    description: ClassVar[str] = (
        "Ticks its child once per element of vector_in, writing the element to out and its index to index; "
        "FAILURE as soon as the child fails, SUCCESS after the last element (at once for an empty vector)."
    )
    ports = (
        InputPort("vector_in", PortType.ANY_LIST, description="The vector to iterate over."),
        OutputPort("out", PortType.ANY, "The current element."),
        OutputPort("index", PortType.UINT, "The current element's index, from 0."),
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.items: list[Any] | None = None
        self.position = 0

    def run(self) -> TickGenerator:
        if self.items is None:
            self.items, self.position = self.get_input("vector_in"), 0
        self.status = Status.RUNNING
        while self.position < len(self.items):
            if self.child.status is not Status.RUNNING:
                self.set_output("out", self.items[self.position])
                self.set_output("index", self.position)
            was_idle = self.child.status is Status.INVALID
            result = yield from self.tick_child(self.child)
            if result is Status.RUNNING:
                return Status.RUNNING
            halt_child(self.child)
            if result is Status.FAILURE:
                self.items = None
                self.feedback_message = f"the child failed at element {self.position}"
                return Status.FAILURE
            self.position += 1
            if was_idle and self.position < len(self.items) and result in COMPLETED:
                return Status.RUNNING  # one element per tick: the loop stays interruptible
        self.items = None
        return Status.SUCCESS

    def halt(self) -> None:
        self.items = None
        super().halt()


NODES = (
    CreatePoseStamped,
    ResetVector,
    ResetPoseStampedVector,
    PushBackVector,
    GetElementOfVector,
    GetSizeOfVector,
    ForEach,
)
