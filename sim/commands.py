"""The simulated cell's command: ``record-demos`` (oracle demonstrations as a LeRobot dataset).

Registered in the ``objective.commands`` entry-point group (see ``runtime.app.command.Command``).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from runtime.app.command import EXIT_BAD_INPUT, EXIT_FAILURE, EXIT_SUCCESS, Command
from runtime.errors import ObjectiveError
from runtime.extras import missing_module_message
from runtime.tree.registry import Registry


def _arguments(demos: argparse.ArgumentParser) -> None:
    demos.add_argument("out", type=Path, help="dataset folder to create")
    demos.add_argument("--episodes", type=int, default=10, help="episodes to record (default 10)")
    demos.add_argument("--seed", type=int, default=0, help="seed of the first episode's layout; episode i uses seed+i")
    demos.add_argument("--world", metavar="NAME", help="world to record in (default: vla_sim if installed, else kinematic)")
    demos.add_argument("--image-size", type=int, default=128, metavar="PX", help="camera frames, square (default 128)")
    demos.add_argument("--steps", type=int, default=250, help="policy steps (0.1 s) recorded per episode (default 250)")
    demos.add_argument("--prompt", default="stack the blue cube on the green cube", help="the task, as the oracle reads it")
    demos.add_argument("--keep-failed", action="store_true", help="keep episodes whose stack check failed")
    demos.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    demos.add_argument("--workers", type=int, default=1, metavar="N",
                       help="record N episodes at once, each in its own process (default 1)")
    demos.add_argument("--cameras", default="scene,wrist,overview", metavar="A,B",
                       help="cameras kept in the dataset (default scene,wrist,overview)")
    demos.add_argument("--gripper-velocity", type=float, default=None, metavar="RAD_S",
                       help="the oracle's gripper speed while recording (default: the oracle's, 1 rad/s)")
    demos.add_argument("--motion-noise", type=float, default=0.0, metavar="RAD",
                       help="peak smooth offset added to the executed arm motion, labels staying the oracle's plan "
                            "(recovery demonstrations; default 0: none)")
    demos.add_argument("--hold-after-plan", type=float, default=None, metavar="S",
                       help="stop taking frames this long after the oracle's plan ends (default: take --steps frames)")


def _record_demos(args: argparse.Namespace, registry: Registry) -> int:
    from .demos import DemoOptions, record_demos

    try:
        summary = record_demos(DemoOptions(
            episodes=args.episodes, seed=args.seed, out=args.out, world=args.world, image_size=args.image_size,
            total_steps=args.steps, prompt=args.prompt, keep_failed=args.keep_failed, overwrite=args.overwrite,
            workers=args.workers, cameras=tuple(c.strip() for c in args.cameras.split(",") if c.strip()),
            gripper_velocity=args.gripper_velocity, motion_noise_rad=args.motion_noise, hold_after_plan_s=args.hold_after_plan,
        ))
    except ObjectiveError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ModuleNotFoundError as err:
        print(f"error: objective record-demos writes a LeRobot dataset: {missing_module_message(err.name or str(err))}",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    except RuntimeError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_FAILURE
    dropped = f", dropped seeds {summary.episodes_dropped}" if summary.episodes_dropped else ""
    print(f"{summary.out}: {summary.episodes_kept} episodes, {summary.frames} frames from world '{summary.world}'{dropped}")
    return EXIT_SUCCESS


RECORD_DEMOS = Command("record oracle demonstrations in the cell as a local LeRobot dataset (needs the LeRobot extra: `make lerobot`)",
                       _arguments, _record_demos)


def _sim_robot_arguments(robot: argparse.ArgumentParser) -> None:
    robot.add_argument("--world", default="vla_sim", choices=("vla_sim", "kinematic"), help="the cell to host (default vla_sim)")
    robot.add_argument("--seed", type=int, default=0, help="seed of the cubes' layout")
    robot.add_argument("--world-option", action="append", type=_key_value, default=[], metavar="KEY=VALUE",
                       help="an option of the world, as for `objective run` (repeatable)")
    robot.add_argument("--node-name", default="sim_robot", metavar="NAME", help="the ROS 2 node (default sim_robot)")
    robot.add_argument("--describe", type=Path, metavar="DIR",
                       help="write the robot's description (MJCF, SRDF, limits, couplings, waypoints) into DIR "
                            "for `objective run --world robot`, print its options and exit")


def _key_value(text: str) -> tuple[str, str]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return key, value


def _sim_robot(args: argparse.Namespace, registry: Registry) -> int:
    from runtime.errors import ObjectiveError
    from runtime.io.interrupt import StopRequest, stop_on_signals

    from .robot_node import SimRobotOptions, describe, print_summary, run_sim_robot

    if args.describe is not None:
        described = describe(args.describe)
        print(" ".join(f"--world-option {option}" for option in described))
        return EXIT_SUCCESS
    options = SimRobotOptions(world=args.world, seed=args.seed, world_options=dict(args.world_option), node_name=args.node_name)
    with stop_on_signals(StopRequest()) as stop:
        try:
            summary = run_sim_robot(options, stop)
        except (ObjectiveError, ValueError) as err:
            print(f"error: {err}", file=sys.stderr)
            return EXIT_BAD_INPUT
    print_summary(summary)
    return EXIT_SUCCESS  # a stop signal is how a robot's process ends


SIM_ROBOT = Command("host the simulated cell alone on ROS 2, a robot for `objective run --ros --world robot`",
                    _sim_robot_arguments, _sim_robot)
