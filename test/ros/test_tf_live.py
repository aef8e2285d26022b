"""The live ``/tf_static`` path with a real ``tf2_msgs``.

tf2_msgs is not on PyPI, so the test builds it, as a colcon build of the package would,
from the ``.msg`` text with the rosidl generators installed with rclpy's wheels
(``test/support/build_tf2_msgs.py``: generated C structs, introspection/Fast DDS/dispatch
type supports and the Python module, compiled with gcc). Then ``rectify_node`` runs in its
own process with that tf2_msgs importable, and a subscriber process that starts *after* it
receives the latched transforms, as RViz or ``tf2_ros`` would.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from canopy_stereo.geometry.frames import quaternion_to_rotation, stereo_transforms  # noqa: E402
from canopy_stereo.geometry.rectification import fusiello_rectify  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402
from canopy_stereo.ros.context import private_domain_id  # noqa: E402
from test.support.build_tf2_msgs import environment  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
pytestmark = [pytest.mark.ros, pytest.mark.slow]

LISTENER = r"""
import json, sys, time
import rclpy
from rclpy.qos import QoSProfile, DurabilityPolicy, ReliabilityPolicy, HistoryPolicy
from tf2_msgs.msg import TFMessage
rclpy.init()
node = rclpy.create_node("tf_listener")
got = []
qos = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                 durability=DurabilityPolicy.TRANSIENT_LOCAL)  # tf2_ros's static listener QoS
node.create_subscription(TFMessage, "/tf_static", got.append, qos)
deadline = time.monotonic() + float(sys.argv[1])
while not got and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
out = [{"parent": t.header.frame_id, "child": t.child_frame_id,
        "t": [t.transform.translation.x, t.transform.translation.y, t.transform.translation.z],
        "q": [t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w]}
       for m in got for t in m.transforms]
print(json.dumps(out))
rclpy.shutdown()
"""


def _env(build, domain):
    return environment(build, dict(os.environ, ROS_DOMAIN_ID=str(domain),
                                   ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"))


def test_generated_tf2_msgs_is_the_real_type(tf2_msgs_build):
    """The built TFMessage round-trips through rclpy's serializer and matches our bag CDR."""
    code = r"""
import sys
from geometry_msgs.msg import TransformStamped
from rclpy.serialization import deserialize_message, serialize_message
from tf2_msgs.msg import TFMessage
from canopy_stereo.bag import BagWriter
from canopy_stereo.ros.tf import serialize_tf_message
from canopy_stereo.bag.msgdefs import message_definition
t = TransformStamped(child_frame_id="left_camera_optical_frame")
t.header.frame_id = "canopy_world"; t.header.stamp.sec = 7; t.transform.translation.x = 0.25
t.transform.rotation.w = 1.0
m = TFMessage(transforms=[t, t])
ours = deserialize_message(serialize_tf_message(m.transforms), TFMessage)
assert ours == m, (ours, m)
assert deserialize_message(serialize_message(m), TFMessage) == m
print(TFMessage.__module__, message_definition("tf2_msgs/msg/TFMessage").splitlines()[0])
"""
    proc = subprocess.run([sys.executable, "-c", code], env=_env(tf2_msgs_build, private_domain_id()),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.split() == ["tf2_msgs.msg._tf_message", "geometry_msgs/TransformStamped[]", "transforms"]


def test_rectify_node_publishes_latched_tf_static(tf2_msgs_build):
    """rectify_node (own process) publishes the rig's transforms on /tf_static; a listener
    started afterwards still receives them (transient local), equal to the rig's geometry."""
    domain = private_domain_id()
    env = _env(tf2_msgs_build, domain)
    rig_file = REPO / "config" / "croton_rig.yaml"
    node = subprocess.Popen([sys.executable, "-c", "import sys; from canopy_stereo.ros.nodes.rectify import main; "
                             "sys.exit(main())", "--ros-args", "--params-file", str(rig_file)],
                            env=env, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(3.0)  # the node is up and has published before the listener exists
        assert node.poll() is None
        listener = subprocess.run([sys.executable, "-c", LISTENER, "30"], env=env, capture_output=True,
                                  text=True, timeout=90)
        assert listener.returncode == 0, listener.stderr[-3000:]
        got = json.loads(listener.stdout.strip().splitlines()[-1])
    finally:
        node.terminate()
        _, err = node.communicate(timeout=30)
    assert "no /tf_static" not in err
    rig = load_rig(rig_file)
    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    want = {(p, c): T for p, c, T in stereo_transforms(rig, rect)}
    assert {(g["parent"], g["child"]) for g in got} == set(want)
    for g in got:
        T = want[(g["parent"], g["child"])]
        np.testing.assert_allclose(g["t"], T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(quaternion_to_rotation(g["q"]), T[:3, :3], atol=1e-9)
