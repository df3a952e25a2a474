"""Compose and compile the Shadow Hand MJCF of gymnasium-robotics into a plain-data :class:`HandSpec`.

Source of truth
---------------
``gymnasium_robotics/envs/assets/hand/robot.xml`` is a fragment (a ``<body>`` tree that expects the
defaults of ``shared.xml`` and the meshes of ``shared_asset.xml``).  :func:`compose_hand_xml` wraps it
in memory: a ``<mujoco>`` root with the compiler settings of the package's own scenes (radians, local
coordinates) and an *absolute* ``meshdir`` (``../stls/hand`` of the package), plus ``<include>``s of
the three files by absolute path.  Nothing is copied into the repository; the package is located
with ``importlib.util.find_spec`` so that gymnasium-robotics (and gymnasium) is never imported.

Every number used downstream (body frames, joint axes / limits, geom sizes and poses, inertials,
mesh frames, the J0-J1 coupling) is read from the model compiled by MuJoCo
(``mujoco.MjModel.from_xml_string``), so Euler angles, ``axisangle`` and default classes have already
been resolved by MuJoCo itself.

Choices (with reasons)
----------------------
* **Names** drop the ``robot0:`` prefix: bodies ``palm``, ``ffproximal`` ...; joints ``FFJ3`` ...
* **Wrist.**  WRJ1 and WRJ0 are held at 0 (the paper's hand has 22 DoF).  The palm body is the root
  of the model; wrist and forearm are rigidly attached to it (fixed links in the URDF).  Both wrist
  hinges have ``pos = 0``, so at 0 the palm frame is exactly the MJCF palm body frame.
* **Collision geoms** are the geoms of class ``robot0:DC_Hand``, recognised in the compiled model as
  group 4 with a non-zero ``contype`` or ``conaffinity``: 16 capsules (wrist, 3 per finger,
  3 on the thumb), 3 boxes (palm0, palm1, lfmetacarpal) and the forearm's convex mesh.  The two 1 mm
  boxes ``V_thbase`` / ``V_thhub`` collide in MuJoCo (they inherit ``asset_class``) but are
  1 mm filler boxes in group 1 that sit inside the thumb capsules: they are left out.
* **Forearm.**  Its collision geom is a convex mesh (a near-cylinder of radius ~68 mm, length ~23 cm).
  It is replaced by its bounding cylinder along the mesh's longest principal axis (the compiled geom
  frame is the mesh's inertia frame), so analytic distances stay exact for a conservative shape.
* **Coupling.**  On FF/MF/RF/LF the fixed tendon ``T_xxJ1c`` has length ``L = c0*q0 + c1*q1`` with
  ``c0 = 0.00705``, ``c1 = -0.00805`` and a limited range of +-1 mm around 0.  Its nominal (mid-range)
  solution ``q0 = (L_mid - c1*q1) / c0`` is the coupling used here: J0 = 1.1418 * J1 (clamped to J0's
  range).  Coupling tendons are recognised as fixed tendons over exactly two joints with
  coefficients of opposite sign; the follower is the joint deeper in the tree.
"""

import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import mujoco
import numpy as np

from components.errors import MultigraspError

#: Python package that ships the Shadow Hand MJCF.
MJCF_PACKAGE = "gymnasium_robotics"
#: Folder of ``robot.xml``, ``shared.xml`` and ``shared_asset.xml`` inside that package.
MJCF_SUBDIR = Path("envs/assets/hand")
#: Mesh folder relative to :data:`MJCF_SUBDIR` (the ``meshdir`` of the package's own scenes).
MESH_SUBDIR = Path("../stls/hand")
#: Prefix of every name in the gymnasium-robotics hand.
NAME_PREFIX = "robot0:"
#: Name (without prefix) of the root body of the 22-DoF hand.
PALM_BODY = "palm"
#: Bodies that are rigidly attached to the palm while the wrist hinges are held at 0, child first.
WRIST_BODIES = ("wrist", "forearm")
#: Wrist hinges, held at 0.
WRIST_JOINTS = ("WRJ1", "WRJ0")
#: MuJoCo geom group of the collision class ``robot0:DC_Hand``.
COLLISION_GROUP = 4
#: MuJoCo geom group of the visual class ``robot0:D_Vizual``.
VISUAL_GROUP = 1


@dataclass(frozen=True)
class BodySpec:
    """One body of the hand: its frame relative to its parent and its inertial (MuJoCo convention)."""

    name: str
    parent: Optional[str]  # None for the palm (root); the wrist hangs from the palm, the forearm from the wrist
    pos: np.ndarray  # (3,) body frame origin in the parent frame
    quat: np.ndarray  # (4,) w, x, y, z: body frame orientation in the parent frame
    mass: float
    inertia: np.ndarray  # (3,) principal moments
    ipos: np.ndarray  # (3,) centre of mass in the body frame
    iquat: np.ndarray  # (4,) w, x, y, z: principal axes in the body frame
    joint: Optional[str]  # the hinge between parent and this body (None: rigid)


@dataclass(frozen=True)
class JointSpec:
    """One hinge: axis in its body frame (through the body origin), limits and dynamics."""

    name: str
    body: str
    axis: np.ndarray  # (3,) unit axis in the child body frame
    lower: float  # rad
    upper: float  # rad
    damping: float
    frictionloss: float
    armature: float
    force_limit: float  # N m: |forcerange| of the actuator that drives it (the leader's for followers)


@dataclass(frozen=True)
class GeomSpec:
    """One collision primitive, pose in its body frame; its local z axis is the capsule/cylinder axis."""

    name: str
    body: str
    kind: str  # "capsule" | "box" | "cylinder"
    size: np.ndarray  # (3,) capsule / cylinder: (radius, half-length, 0); box: half extents
    pos: np.ndarray  # (3,) centre in the body frame
    quat: np.ndarray  # (4,) w, x, y, z: orientation in the body frame


@dataclass(frozen=True)
class VisualSpec:
    """One visual mesh: the STL file and the pose of the *file's* frame in the body frame."""

    name: str
    body: str
    mesh_file: Path  # absolute
    scale: np.ndarray  # (3,)
    pos: np.ndarray  # (3,)
    quat: np.ndarray  # (4,) w, x, y, z
    rgba: np.ndarray  # (4,)


@dataclass(frozen=True)
class CouplingSpec:
    """Tendon coupling: q[follower] = offset + ratio * q[leader] (then clamped to the follower's range)."""

    tendon: str
    follower: str
    leader: str
    ratio: float
    offset: float


@dataclass(frozen=True)
class HandSpec:
    """Everything the hand model needs from the MJCF, as plain numbers (see the module docstring)."""

    xml: str  # the composed MJCF wrapper (absolute includes and meshdir)
    mjcf_dir: Path
    bodies: tuple  # of BodySpec: palm first, then the finger bodies in MJCF (= chain) order, then wrist, forearm
    joints: tuple  # of JointSpec: the 22 finger hinges in MJCF order
    collision_geoms: tuple  # of GeomSpec, MJCF order
    visuals: tuple  # of VisualSpec, MJCF order
    couplings: tuple  # of CouplingSpec

    def body(self, name: str) -> BodySpec:
        """The body called ``name``."""
        return next(b for b in self.bodies if b.name == name)

    def joint(self, name: str) -> JointSpec:
        """The joint called ``name``."""
        return next(j for j in self.joints if j.name == name)


def mjcf_dir() -> Path:
    """Absolute folder of the installed Shadow Hand MJCF (found without importing the package)."""
    spec = importlib.util.find_spec(MJCF_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise MultigraspError(
            f"the Shadow Hand model needs the '{MJCF_PACKAGE}' package: install the project's pinned "
            f"dependencies (gymnasium-robotics==1.4.2)"
        )
    folder = Path(list(spec.submodule_search_locations)[0]) / MJCF_SUBDIR
    if not (folder / "robot.xml").is_file():
        raise MultigraspError(f"no robot.xml in {folder}: reinstall gymnasium-robotics==1.4.2")
    return folder


def compose_hand_xml(folder: Path) -> str:
    """The MJCF wrapper around ``robot.xml``: absolute includes of the three files and absolute meshdir."""
    mesh_dir = (folder / MESH_SUBDIR).resolve()
    return (
        '<mujoco model="shadow_hand">\n'
        f'  <compiler angle="radian" coordinate="local" meshdir="{mesh_dir}"/>\n'
        f'  <include file="{folder / "shared.xml"}"/>\n'
        f'  <asset><include file="{folder / "shared_asset.xml"}"/></asset>\n'
        f'  <worldbody><include file="{folder / "robot.xml"}"/></worldbody>\n'
        "</mujoco>\n"
    )


def _strip(name: str) -> str:
    """Name without the ``robot0:`` prefix."""
    return name[len(NAME_PREFIX):] if name.startswith(NAME_PREFIX) else name


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix of a w, x, y, z unit quaternion (MuJoCo's convention)."""
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, dtype=np.float64))
    return mat.reshape(3, 3)


def matrix_to_quat(mat: np.ndarray) -> np.ndarray:
    """(4,) w, x, y, z unit quaternion of a (3, 3) rotation matrix."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(mat, dtype=np.float64).reshape(9))
    return quat


def invert_pose(pos: np.ndarray, quat: np.ndarray) -> tuple:
    """(pos, quat) of the inverse of the rigid transform x -> R(quat) x + pos."""
    rot_t = quat_to_matrix(quat).T
    return -rot_t @ np.asarray(pos, dtype=np.float64), matrix_to_quat(rot_t)


def _bounding_cylinder(model: mujoco.MjModel, geom_id: int) -> tuple:
    """Bounding cylinder of a mesh geom along its longest principal axis: (size, pos, quat) in the body frame.

    The compiled mesh vertices are expressed in the geom frame, which MuJoCo aligns with the mesh's
    principal axes; the cylinder axis is the coordinate axis of largest extent k, its centre the
    middle of the bounding box, its half-length half that extent and its radius the largest distance
    of a vertex from the axis.
    """
    mesh_id = int(model.geom_dataid[geom_id])
    start, count = int(model.mesh_vertadr[mesh_id]), int(model.mesh_vertnum[mesh_id])
    verts = np.asarray(model.mesh_vert[start:start + count], dtype=np.float64)  # (V, 3) geom frame
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    axis = int(np.argmax(hi - lo))
    # columns = the geom-frame directions of the cylinder's x, y, z (cyclic, so right-handed)
    perm = np.eye(3)[:, [(axis + 1) % 3, (axis + 2) % 3, axis]]
    centre = 0.5 * (lo + hi)
    radial = (verts - centre) @ perm[:, :2]  # (V, 2)
    radius = float(np.sqrt((radial ** 2).sum(axis=1)).max())
    half_length = 0.5 * float(hi[axis] - lo[axis])
    rot_geom = quat_to_matrix(model.geom_quat[geom_id])
    pos = model.geom_pos[geom_id] + rot_geom @ centre
    quat = matrix_to_quat(rot_geom @ perm)
    return np.array([radius, half_length, 0.0]), pos, quat


def _collision_geom(model: mujoco.MjModel, geom_id: int) -> GeomSpec:
    """The :class:`GeomSpec` of one compiled collision geom (mesh -> bounding cylinder)."""
    gtype = int(model.geom_type[geom_id])
    name = _strip(model.geom(geom_id).name)
    body = _strip(model.body(int(model.geom_bodyid[geom_id])).name)
    pos, quat = np.array(model.geom_pos[geom_id]), np.array(model.geom_quat[geom_id])
    size = np.array(model.geom_size[geom_id])
    if gtype == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return GeomSpec(name, body, "capsule", np.array([size[0], size[1], 0.0]), pos, quat)
    if gtype == mujoco.mjtGeom.mjGEOM_BOX:
        return GeomSpec(name, body, "box", size, pos, quat)
    if gtype == mujoco.mjtGeom.mjGEOM_MESH:
        size, pos, quat = _bounding_cylinder(model, geom_id)
        return GeomSpec(name, body, "cylinder", size, pos, quat)
    raise MultigraspError(f"unsupported collision geom type {gtype} for {name}: reinstall gymnasium-robotics==1.4.2")


def _visual(model: mujoco.MjModel, geom_id: int, mesh_root: Path) -> VisualSpec:
    """The :class:`VisualSpec` of one mesh geom.

    MuJoCo stores mesh vertices re-centred: ``v_c = R_m^T (s * v_file - p_m)`` with ``(p_m, R_m)`` the
    mesh's ``mesh_pos`` / ``mesh_quat``.  A file vertex therefore sits in the body frame at
    ``R_g R_m^T (s v_file) + p_g - R_g R_m^T p_m``.
    """
    mesh_id = int(model.geom_dataid[geom_id])
    file_name = model.paths[int(model.mesh_pathadr[mesh_id]):].split(b"\x00", 1)[0].decode()
    rot_g = quat_to_matrix(model.geom_quat[geom_id])
    rot_m = quat_to_matrix(model.mesh_quat[mesh_id])
    rot = rot_g @ rot_m.T
    pos = model.geom_pos[geom_id] - rot @ model.mesh_pos[mesh_id]
    mat_id = int(model.geom_matid[geom_id])
    rgba = np.array(model.mat_rgba[mat_id] if mat_id >= 0 else model.geom_rgba[geom_id])
    return VisualSpec(
        name=_strip(model.geom(geom_id).name),
        body=_strip(model.body(int(model.geom_bodyid[geom_id])).name),
        mesh_file=(mesh_root / file_name).resolve(),
        scale=np.array(model.mesh_scale[mesh_id]),
        pos=pos,
        quat=matrix_to_quat(rot),
        rgba=rgba,
    )


def _couplings(model: mujoco.MjModel, depth: dict) -> tuple:
    """The J0-J1 tendon couplings (see the module docstring)."""
    couplings = []
    for tendon_id in range(model.ntendon):
        adr, num = int(model.tendon_adr[tendon_id]), int(model.tendon_num[tendon_id])
        if num != 2 or any(int(model.wrap_type[adr + k]) != mujoco.mjtWrap.mjWRAP_JOINT for k in range(num)):
            continue
        joints = [_strip(model.joint(int(model.wrap_objid[adr + k])).name) for k in range(num)]
        coefs = [float(model.wrap_prm[adr + k]) for k in range(num)]
        if coefs[0] * coefs[1] >= 0.0:
            continue
        follower_k = 0 if depth[joints[0]] > depth[joints[1]] else 1
        leader_k = 1 - follower_k
        length_mid = float(np.mean(model.tendon_range[tendon_id]))
        couplings.append(
            CouplingSpec(
                tendon=_strip(model.tendon(tendon_id).name),
                follower=joints[follower_k],
                leader=joints[leader_k],
                ratio=-coefs[leader_k] / coefs[follower_k],
                offset=length_mid / coefs[follower_k],
            )
        )
    return tuple(couplings)


def load_hand_spec() -> HandSpec:
    """Compose the MJCF, compile it with MuJoCo and read the hand out of the compiled model."""
    folder = mjcf_dir()
    xml = compose_hand_xml(folder)
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except ValueError as exc:  # MuJoCo reports XML errors as ValueError
        raise MultigraspError(f"MuJoCo could not compile {folder / 'robot.xml'}: {exc}") from exc

    names = [_strip(model.body(i).name) for i in range(model.nbody)]
    parent = {names[i]: names[int(model.body_parentid[i])] for i in range(1, model.nbody)}
    body_joint = {}
    joint_depth = {}
    for j in range(model.njnt):
        body_name = names[int(model.jnt_bodyid[j])]
        body_joint[body_name] = _strip(model.joint(j).name)
        depth, node = 0, body_name
        while node in parent:
            node, depth = parent[node], depth + 1
        joint_depth[_strip(model.joint(j).name)] = depth

    def under_palm(name: str) -> bool:
        while name in parent:
            if name == PALM_BODY:
                return True
            name = parent[name]
        return False

    finger_bodies = [n for n in names if n != PALM_BODY and under_palm(n)]
    ordered = [PALM_BODY] + finger_bodies + list(WRIST_BODIES)
    # the wrist chain is re-rooted at the palm: wrist hangs from the palm, forearm from the wrist
    reroot = {WRIST_BODIES[0]: PALM_BODY, WRIST_BODIES[1]: WRIST_BODIES[0]}
    bodies = []
    for name in ordered:
        i = names.index(name)
        joint = body_joint.get(name)
        pos, quat = np.array(model.body_pos[i]), np.array(model.body_quat[i])
        if name == PALM_BODY:  # the root: its frame *is* the reference frame
            pos, quat = np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
        if name in reroot:  # pose of this body in its former child = inverse of the child's pose in it
            child = names.index(reroot[name])
            pos, quat = invert_pose(model.body_pos[child], model.body_quat[child])
        bodies.append(
            BodySpec(
                name=name,
                parent=None if name == PALM_BODY else reroot.get(name, parent[name]),
                pos=pos,
                quat=quat,
                mass=float(model.body_mass[i]),
                inertia=np.array(model.body_inertia[i]),
                ipos=np.array(model.body_ipos[i]),
                iquat=np.array(model.body_iquat[i]),
                joint=None if joint in WRIST_JOINTS else joint,
            )
        )

    couplings = _couplings(model, joint_depth)
    leader_of = {c.follower: c.leader for c in couplings}
    force_limit = {}
    for a in range(model.nu):
        if int(model.actuator_trntype[a]) == mujoco.mjtTrn.mjTRN_JOINT:
            jname = _strip(model.joint(int(model.actuator_trnid[a, 0])).name)
            force_limit[jname] = float(np.abs(model.actuator_forcerange[a]).max())
    joints = []
    for j in range(model.njnt):
        name = _strip(model.joint(j).name)
        if name in WRIST_JOINTS:
            continue
        dof = int(model.jnt_dofadr[j])
        joints.append(
            JointSpec(
                name=name,
                body=names[int(model.jnt_bodyid[j])],
                axis=np.array(model.jnt_axis[j]),
                lower=float(model.jnt_range[j, 0]),
                upper=float(model.jnt_range[j, 1]),
                damping=float(model.dof_damping[dof]),
                frictionloss=float(model.dof_frictionloss[dof]),
                armature=float(model.dof_armature[dof]),
                force_limit=force_limit[leader_of.get(name, name)],
            )
        )

    collision, visuals = [], []
    mesh_root = (folder / MESH_SUBDIR).resolve()
    for g in range(model.ngeom):
        group = int(model.geom_group[g])
        if group == COLLISION_GROUP and (model.geom_contype[g] or model.geom_conaffinity[g]):
            collision.append(_collision_geom(model, g))
        elif group == VISUAL_GROUP and int(model.geom_type[g]) == mujoco.mjtGeom.mjGEOM_MESH:
            visuals.append(_visual(model, g, mesh_root))

    return HandSpec(
        xml=xml,
        mjcf_dir=folder,
        bodies=tuple(bodies),
        joints=tuple(joints),
        collision_geoms=tuple(collision),
        visuals=tuple(visuals),
        couplings=couplings,
    )
