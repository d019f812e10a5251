"""RViz markers of the estimator's model (``/herd/model/markers``): the field's arrows at
its centres (mean over agents), the centres, and the last one-step predictions."""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point, Pose
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray


def model_markers(core, frame: str, prediction=None) -> MarkerArray:
    """Markers of an :class:`~herd_ros.estimation.online_fit.OnlineHerdEstimator`'s model."""
    centers = core.basis.centers
    field = core.mean_field(centers)
    spacing = float(np.mean(core.grid.spacing))
    top = float(np.max(np.hypot(field[:, 0], field[:, 1]))) if len(field) else 0.0
    scale = 0.8 * spacing / top if top > 0 else 0.0
    markers = [_points_marker(frame, 'centres', 0, centers, 0.2 * spacing,
                              ColorRGBA(r=0.6, g=0.6, b=0.6, a=0.8))]
    for k, (c, g) in enumerate(zip(centers, field)):
        m = Marker(type=Marker.ARROW, action=Marker.ADD, ns='field', id=k)
        m.header.frame_id = frame
        m.points = [Point(x=float(c[0]), y=float(c[1])),
                    Point(x=float(c[0] + scale * g[0]), y=float(c[1] + scale * g[1]))]
        m.scale.x, m.scale.y, m.scale.z = 0.05 * spacing, 0.1 * spacing, 0.1 * spacing
        m.color = ColorRGBA(r=0.1, g=0.4, b=0.9, a=0.9)
        m.pose.orientation.w = 1.0
        markers.append(m)
    pred = prediction
    if pred is not None:
        markers.append(_points_marker(frame, 'predictions', 0, np.nan_to_num(pred),
                                      0.1 * spacing, ColorRGBA(r=0.9, g=0.3, b=0.1, a=1.0)))
    return MarkerArray(markers=markers)


def pose_at(x: float, y: float) -> Pose:
    """A Pose at (x, y, 0) with no rotation."""
    pose = Pose()
    pose.position.x, pose.position.y = float(x), float(y)
    pose.orientation.w = 1.0
    return pose


def _points_marker(frame, ns, mid, points, size, color) -> Marker:
    m = Marker(type=Marker.SPHERE_LIST, action=Marker.ADD, ns=ns, id=mid)
    m.header.frame_id = frame
    m.pose.orientation.w = 1.0
    m.scale.x = m.scale.y = m.scale.z = float(size)
    m.color = color
    m.points = [Point(x=float(x), y=float(y)) for x, y in points]
    return m
