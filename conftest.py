"""Test-wide environment: ROS discovery stays on loopback, MuJoCo renders offscreen."""
import os

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", str(40 + os.getpid() % 60))
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("ROS_LOG_DIR", os.path.join(os.path.dirname(__file__), "build", "ros_log"))
os.environ.setdefault("HF_HUB_OFFLINE", "1")
