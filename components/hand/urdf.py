"""URDF export of the compiled Shadow Hand for PyBullet, and PyBullet index helpers.

PyBullet cannot load the MJCF (it rejects ``<include>`` and ignores default classes), so the URDF is
written from the same :class:`~components.hand.mjcf.HandSpec` the torch model uses:

* **Links** are the model's ``link_names`` (MJCF body names without ``robot0:``).  The base link is
  ``palm``; ``wrist`` and ``forearm`` (when part of the model) hang from it through fixed joints
  (``palm_to_wrist``, ``wrist_to_forearm``) at their constant palm-frame poses (WRJ1 = WRJ0 = 0).
* **Joints**: 22 revolute joints named like the MJCF hinges (``FFJ3`` ...); URDF joint origin =
  MJCF body pose in its parent (every hinge sits at its body origin), axis = MJCF axis, limits =
  MJCF range, effort = |forcerange| of the actuator that drives it (J0: its J1's actuator),
  velocity = ``HandConfig.urdf_joint_velocity_limit``, damping / friction = MJCF damping /
  frictionloss.  PyBullet does not enforce the J0-J1 tendon: control J0 with
  ``HandModel.expand_actuated``.
* **Collision** = exactly the analytic primitives of :mod:`components.hand.geometry`:
  ``<capsule radius length>`` (PyBullet's URDF extension, axis z, ``length`` = cylinder part
  = 2 x half-length), ``<box>`` and, for the forearm, ``<cylinder>``.  So what the torch model
  calls penetration-free is penetration-free in PyBullet too.  PyBullet turns URDF cylinders into
  convex meshes unless the URDF is loaded with ``flags=pybullet.URDF_USE_IMPLICIT_CYLINDER``.
* **Visual** = the package's STL meshes by absolute path with their MJCF scale (0.001 for the
  millimetre files) at the pose of the file frame (MuJoCo re-centres meshes; see
  :mod:`components.hand.mjcf`), so the URDF is only valid on the machine that wrote it.
* **Inertials** = compiled MuJoCo body mass, centre of mass, principal inertia and its axes.

Orientations are written as URDF ``rpy`` (fixed-axis roll, pitch, yaw: R = Rz(y) Ry(p) Rx(r)).
PyBullet numbers a link like the joint above it: use :func:`pybullet_indices` to map names to
indices instead of assuming an order.
"""

import xml.etree.ElementTree as ET

import numpy as np
from scipy.spatial.transform import Rotation

from components.hand.mjcf import PALM_BODY, GeomSpec, HandSpec

#: Name of the fixed joint that attaches ``child`` to ``parent``.
FIXED_JOINT_NAME = "{parent}_to_{child}"
#: Significant digits of numbers written to the URDF (float64 round-trip).
DIGITS = 17


def _num(values) -> str:
    """Space-separated numbers at full float64 precision."""
    return " ".join(f"{float(v):.{DIGITS}g}" for v in np.atleast_1d(values))


def quat_to_rpy(quat: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw of a w, x, y, z quaternion: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return Rotation.from_quat(np.asarray(quat, dtype=np.float64), scalar_first=True).as_euler("xyz")


def _origin(parent: ET.Element, pos: np.ndarray, quat: np.ndarray) -> None:
    """Append ``<origin xyz rpy>``."""
    ET.SubElement(parent, "origin", xyz=_num(pos), rpy=_num(quat_to_rpy(quat)))


def _geometry(parent: ET.Element, geom: GeomSpec) -> None:
    """Append the ``<geometry>`` of one collision primitive."""
    node = ET.SubElement(parent, "geometry")
    if geom.kind == "capsule":
        ET.SubElement(node, "capsule", radius=_num(geom.size[0]), length=_num(2.0 * geom.size[1]))
    elif geom.kind == "box":
        ET.SubElement(node, "box", size=_num(2.0 * geom.size))
    else:
        ET.SubElement(node, "cylinder", radius=_num(geom.size[0]), length=_num(2.0 * geom.size[1]))


def build_urdf(spec: HandSpec, link_names: list, geoms: list, robot_name: str, velocity_limit: float) -> str:
    """The URDF text of the hand restricted to ``link_names`` with collision primitives ``geoms``."""
    robot = ET.Element("robot", name=robot_name)
    bodies = [b for b in spec.bodies if b.name in link_names]
    colours = {}
    for visual in spec.visuals:
        colours.setdefault(tuple(np.round(visual.rgba, 6)), f"visual_{len(colours)}")
    for rgba, name in colours.items():
        ET.SubElement(ET.SubElement(robot, "material", name=name), "color", rgba=_num(rgba))

    for body in bodies:
        link = ET.SubElement(robot, "link", name=body.name)
        inertial = ET.SubElement(link, "inertial")
        _origin(inertial, body.ipos, body.iquat)
        ET.SubElement(inertial, "mass", value=_num(body.mass))
        ET.SubElement(inertial, "inertia", ixx=_num(body.inertia[0]), iyy=_num(body.inertia[1]),
                      izz=_num(body.inertia[2]), ixy="0", ixz="0", iyz="0")
        for visual in (v for v in spec.visuals if v.body == body.name):
            node = ET.SubElement(link, "visual", name=visual.name)
            _origin(node, visual.pos, visual.quat)
            ET.SubElement(ET.SubElement(node, "geometry"), "mesh", filename=str(visual.mesh_file),
                          scale=_num(visual.scale))
            ET.SubElement(node, "material", name=colours[tuple(np.round(visual.rgba, 6))])
        for geom in (g for g in geoms if g.body == body.name):
            node = ET.SubElement(link, "collision", name=geom.name)
            _origin(node, geom.pos, geom.quat)
            _geometry(node, geom)

    for body in bodies:
        if body.name == PALM_BODY:
            continue
        if body.joint is None:
            joint = ET.SubElement(robot, "joint", name=FIXED_JOINT_NAME.format(parent=body.parent, child=body.name),
                                  type="fixed")
        else:
            spec_joint = spec.joint(body.joint)
            joint = ET.SubElement(robot, "joint", name=body.joint, type="revolute")
        ET.SubElement(joint, "parent", link=body.parent)
        ET.SubElement(joint, "child", link=body.name)
        _origin(joint, body.pos, body.quat)
        if body.joint is not None:
            ET.SubElement(joint, "axis", xyz=_num(spec_joint.axis))
            ET.SubElement(joint, "limit", lower=_num(spec_joint.lower), upper=_num(spec_joint.upper),
                          effort=_num(spec_joint.force_limit), velocity=_num(velocity_limit))
            ET.SubElement(joint, "dynamics", damping=_num(spec_joint.damping), friction=_num(spec_joint.frictionloss))
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def pybullet_indices(body_id: int, client_id: int) -> tuple:
    """Name -> PyBullet index maps of a loaded hand: (joint index of each joint name, link index of each
    link name).  The base link (palm) has index -1; a link's index is that of the joint above it."""
    import pybullet  # local: only this helper needs PyBullet

    joints, links = {}, {PALM_BODY: -1}
    for index in range(pybullet.getNumJoints(body_id, physicsClientId=client_id)):
        info = pybullet.getJointInfo(body_id, index, physicsClientId=client_id)
        joints[info[1].decode()] = index
        links[info[12].decode()] = index
    return joints, links
