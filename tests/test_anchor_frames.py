"""map -> anchor_<id> (what locate --ros2 puts on /tf_static) turns anchor-frame vectors into the
site's frame exactly as the locator's own rotation does (host/estimation/anchors3d.py), checked
against scipy's Rotation, which rfhoming did not write."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rfhoming.host.export import frames
from rfhoming.host.site import Anchor, Calibration

angle = st.floats(-180, 180)


@settings(max_examples=200, deadline=None)
@given(yaw=angle, pitch=st.floats(-90, 90), roll=angle, offset=st.floats(-45, 45))
def test_an_anchors_transform_is_its_rotation(yaw: float, pitch: float, roll: float, offset: float) -> None:
    anchor = Anchor("west", "CCF9578E0A01", None, (1.0, 2.0, 3.0), yaw, pitch, roll)
    anchor = replace(anchor, calibration=Calibration(yaw_offset_deg=offset))
    (tf,) = frames.anchor_mounts(SimpleNamespace(anchors=[anchor]))
    q = tf.quaternion()
    assert (tf.parent, tf.child, tf.xyz) == ("map", "anchor_CCF9578E0A01", (1.0, 2.0, 3.0))
    assert np.allclose(Rotation.from_quat([q["x"], q["y"], q["z"], q["w"]]).as_matrix(), anchor.rotation(), atol=1e-9)
