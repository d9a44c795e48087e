"""The mounting of every gyro as ROS consumes it: tf2 static transforms (launch files, YAML) and URDF fixed joints.

Direction (the most common mix-up, stated in every file written here): the PARENT frame is the reference gyro
(gyro 1), each CHILD frame another gyro k, and the transform is ``T_parent_child``: its rotation is
``R_1_k`` (``R_1_2`` of a pair, ``R_ref_k[k]`` of an array), which maps vectors in the child's frame into the
parent's (``v_parent = R v_child``). That is the pose of the child in the parent frame: what
``static_transform_publisher ... parent child`` publishes, what ``tf2 lookupTransform(parent, child)``
returns, and what a URDF ``<joint>``'s ``<origin>`` from ``<parent link>`` to ``<child link>`` holds.

Reading rules of the consumers, restated (the tests read the files by them):

* ROS 1 ``tf2_ros static_transform_publisher x y z qx qy qz qw frame_id child_frame_id`` (the launch file's
  ``args``), or ``x y z yaw pitch roll frame_id child_frame_id`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)``;
* ROS 2 ``static_transform_publisher --x --y --z --qx --qy --qz --qw --frame-id --child-frame-id``;
* the YAML is a ``tf2_msgs/TFMessage``: ``transforms`` of ``geometry_msgs/TransformStamped`` (``header.frame_id``
  the parent, ``child_frame_id``, ``transform.translation {x, y, z}``, ``transform.rotation {x, y, z, w}``);
* URDF ``<joint type="fixed">`` with ``<parent link>``, ``<child link>`` and ``<origin xyz rpy>``, ``rpy`` about
  the fixed axes x, then y, then z (``R = Rz(y) Ry(p) Rx(r)``).

The translation is NOT estimated (gyro-only calibration): it is written as zeros and every file says so.
:func:`parse_rotation` reads a rotation given on the command line (``--nominal``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.array_result import ArrayCalibration
from ..core.model import PairCalibration, rotation_forms
from ..errors import FormatError, InputError

_FRAME = re.compile(r"^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")
_NO_TRANSLATION = ("TRANSLATION IS NOT ESTIMATED (gyro-only calibration): x y z = 0 is a placeholder; "
                   "put the lever arm there if you know it.")


@dataclass(frozen=True)
class FrameTransform:
    """The mounting of one gyro against the reference: ``v_parent = R_parent_child @ v_child``.

    Attributes
    ----------
    gyro : int
        The child's gyro number (from 1).
    parent, child : str
        Frame names (the reference gyro's and this gyro's).
    R_parent_child : ndarray (3, 3)
        Rotation of the child's frame into the parent's (the pose of the child in the parent frame).
    rotation_std_deg : ndarray (3,)
        Its 1-sigma per axis of the parent frame (deg).
    """

    gyro: int
    parent: str
    child: str
    R_parent_child: np.ndarray
    rotation_std_deg: np.ndarray

    @property
    def forms(self) -> dict:
        """:func:`~fusion_gyrocal.core.model.rotation_forms` of ``R_parent_child``."""
        return rotation_forms(self.R_parent_child)


def default_frames(n: int) -> list[str]:
    """``gyro1``, ``gyro2``, ...: the gyros' numbers as every message of the library gives them."""
    return [f"gyro{k + 1}" for k in range(n)]


def check_frames(frames, n: int) -> list[str]:
    """``frames`` checked for ``n`` gyros (default :func:`default_frames`).

    Raises
    ------
    InputError
        Another number of names than gyros, a name ROS does not accept, or a name used twice.
    """
    frames = default_frames(n) if frames is None else [str(f) for f in frames]
    if len(frames) != n:
        raise InputError(f"frames: expected {n} frame names (gyro 1 first), got {len(frames)}: {frames!r}")
    bad = [f for f in frames if not _FRAME.match(f)]
    if bad:
        raise InputError(f"frames: expected ROS frame names (letters, digits, '_', '/' between parts), got {bad!r}")
    if len(set(frames)) != n:
        raise InputError(f"frames: expected {n} different names, got {frames!r}")
    return frames


def frame_transforms(cal, frames=None) -> tuple[FrameTransform, ...]:
    """One :class:`FrameTransform` per gyro other than the reference, in gyro order.

    Parameters
    ----------
    cal : PairCalibration or ArrayCalibration
    frames : sequence of str, optional
        Frame name of every gyro, gyro 1 first (default :func:`default_frames`); ROS names (letters, digits,
        ``_`` and ``/`` between them).

    Raises
    ------
    InputError
        Another number of frame names than gyros, a name ROS does not accept, a name used twice, or a result
        with non-finite rotations.
    """
    if isinstance(cal, PairCalibration):
        Rs, ref, sd = [np.eye(3), cal.R_1_2], 0, [np.zeros(3), np.degrees(cal.rotation_std_rad)]
    elif isinstance(cal, ArrayCalibration):
        Rs, ref, sd = list(cal.R_ref_k), cal.reference, list(np.degrees(cal.rotation_std_rad))
    else:
        raise InputError(f"cal: expected a PairCalibration or an ArrayCalibration, got {type(cal).__name__}")
    n = len(Rs)
    frames = check_frames(frames, n)
    if not np.isfinite(np.asarray(Rs)).all():
        raise InputError("cal: expected finite rotations for a transform, got non-finite values")
    return tuple(FrameTransform(k + 1, frames[ref], frames[k], np.asarray(Rs[k], float), np.asarray(sd[k], float))
                 for k in range(n) if k != ref)


def _f(x: float) -> str:
    """A float with every digit (``repr``), never in a form a launch argument parser would misread."""
    return repr(float(x))


def _direction_lines(t: FrameTransform) -> list[str]:
    fm = t.forms
    return [f"gyro {t.gyro}: parent {t.parent} (gyro 1, the reference) -> child {t.child}. The rotation maps vectors "
            f"in {t.child}'s frame into {t.parent}'s (v_{t.parent} = R v_{t.child}): the pose of {t.child} in "
            f"{t.parent}, what lookupTransform('{t.parent}', '{t.child}') returns.",
            f"  quaternion x y z w: {' '.join(f'{v:.9f}' for v in fm['quaternion_xyzw'])}; roll pitch yaw (rad, "
            f"R = Rz(yaw) Ry(pitch) Rx(roll)): {' '.join(f'{v:.9f}' for v in fm['rpy'])}; 1-sigma per axis (deg): "
            f"{', '.join(f'{v:.3g}' for v in t.rotation_std_deg)}"]


def _xml_comment(lines) -> list[str]:
    # "--" may not appear inside an XML comment
    return ["<!--"] + [f"  {line.replace('--', '- -')}" for line in lines] + ["-->"]


def static_transform_args(t: FrameTransform, ros: int = 1) -> str:
    """The arguments of ``static_transform_publisher`` for one transform: ROS 1's positional
    ``x y z qx qy qz qw frame_id child_frame_id``, or ROS 2's named ``--x ... --frame-id ... --child-frame-id``."""
    q = t.forms["quaternion_xyzw"]
    if ros == 1:
        return " ".join(["0.0", "0.0", "0.0", *(_f(v) for v in q), t.parent, t.child])
    if ros == 2:
        named = zip(("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw"), ["0.0"] * 3 + [_f(v) for v in q])
        return " ".join(f"{k} {v}" for k, v in named) + f" --frame-id {t.parent} --child-frame-id {t.child}"
    raise InputError(f"ros: expected 1 or 2, got {ros!r}")


def _launch(transforms, what: str, ros: int) -> str:
    head = [f"tf2 static transforms (ROS {ros} launch) written by fusion_gyrocal from {what}.", _NO_TRANSLATION]
    for t in transforms:
        head += _direction_lines(t)
    lines = ['<?xml version="1.0"?>', "<launch>"] + [f"  {c}" for c in _xml_comment(head)]
    key = "type" if ros == 1 else "exec"
    for t in transforms:
        name = f"gyrocal_{t.parent}_to_{t.child}".replace("/", "_")
        lines.append(f'  <node pkg="tf2_ros" {key}="static_transform_publisher" name="{name}" '
                     f'args="{static_transform_args(t, ros)}" />')
    lines.append("</launch>")
    return "\n".join(lines) + "\n"


def _tf_yaml(transforms, what: str) -> str:
    lines = [f"# tf2_msgs/TFMessage (geometry_msgs/TransformStamped each) written by fusion_gyrocal from {what}.",
             f"# {_NO_TRANSLATION}"]
    for t in transforms:
        lines += [f"# {line}" for line in _direction_lines(t)]
    lines.append("transforms:")
    for t in transforms:
        q = t.forms["quaternion_xyzw"]
        lines += ["  - header:", f'      frame_id: "{t.parent}"', f'    child_frame_id: "{t.child}"',
                  "    transform:", "      translation: {x: 0.0, y: 0.0, z: 0.0}",
                  "      rotation: {" + ", ".join(f"{k}: {_f(v)}" for k, v in zip("xyzw", q)) + "}"]
    return "\n".join(lines) + "\n"


def _urdf(transforms, what: str, robot: str) -> str:
    head = [f"URDF fixed joints written by fusion_gyrocal from {what}. Copy the joints (and links) into your robot "
            "description; each <origin> is the transform from the parent link to the child link.", _NO_TRANSLATION]
    for t in transforms:
        head += _direction_lines(t)
    links = [transforms[0].parent] + [t.child for t in transforms]
    lines = ['<?xml version="1.0"?>', f'<robot name="{robot}">'] + [f"  {c}" for c in _xml_comment(head)]
    lines += [f'  <link name="{name}" />' for name in links]
    for t in transforms:
        rpy = " ".join(_f(v) for v in t.forms["rpy"])
        joint = f"{t.parent}_to_{t.child}".replace("/", "_")
        lines += [f'  <joint name="{joint}" type="fixed">', f'    <parent link="{t.parent}" />', f'    <child link="{t.child}" />',
                  f'    <origin xyz="0.0 0.0 0.0" rpy="{rpy}" />', "  </joint>"]
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def _what(cal) -> str:
    if isinstance(cal, PairCalibration):
        return f"a gyro-pair calibration ({cal.method}, {cal.n_samples} samples)"
    return f"a joint calibration of {cal.n_gyros} gyros ({cal.n_samples} samples)"


def _warning(cal) -> list[str]:
    if isinstance(cal, PairCalibration) and cal.rigid is False:
        return ["WARNING: NOT RIGID: the gyros move relative to each other; the rotation below is not a calibration."]
    return []


def write_ros_frames(cal, folder, *, frames=None, robot: str = "gyrocal_imus") -> tuple[Path, ...]:
    """Write the mounting of every gyro for ROS into ``folder`` (created when missing), each file atomically.

    Files: ``static_transforms.launch`` (ROS 1 roslaunch, ``tf2_ros`` ``static_transform_publisher`` with the
    quaternion), ``static_transforms.launch.xml`` (ROS 2 XML launch, named arguments),
    ``static_transforms.yaml`` (a ``tf2_msgs/TFMessage``) and ``imu_joints.urdf`` (a ``<robot>`` with one link per
    gyro and a fixed joint per non-reference gyro). The direction is that of the module docstring and is stated
    in every file: parent = the reference gyro, child = gyro k, rotation ``R_1_k`` (child vectors into the parent
    frame). Translations are zeros (not estimated), said in every file.

    Parameters
    ----------
    cal : PairCalibration or ArrayCalibration
    folder : str or Path
    frames : sequence of str, optional
        Frame (link) name of every gyro, gyro 1 first (default ``gyro1``, ``gyro2``, ...).
    robot : str
        The URDF's robot name.

    Returns
    -------
    tuple of Path
    """
    from .writers import atomic_write

    transforms = frame_transforms(cal, frames)
    if not transforms:
        raise InputError("cal: expected at least two gyros for a transform, got one")
    if not _FRAME.match(robot):
        raise InputError(f"robot: expected a name of letters, digits and '_', got {robot!r}")
    what = _what(cal)
    warn = _warning(cal)
    folder = Path(folder).expanduser()
    try:
        folder.mkdir(exist_ok=True)
    except OSError as exc:
        raise FormatError(f"{folder}: could not create the folder: {exc}") from None
    texts = {"static_transforms.launch": _launch(transforms, what, 1),
             "static_transforms.launch.xml": _launch(transforms, what, 2),
             "static_transforms.yaml": _tf_yaml(transforms, what),
             "imu_joints.urdf": _urdf(transforms, what, robot)}
    paths = []
    for name, text in texts.items():
        if warn:
            text = (text.replace("<launch>", "<launch>\n  " + "\n  ".join(_xml_comment(warn)), 1)
                    .replace(f'<robot name="{robot}">', f'<robot name="{robot}">\n  ' + "\n  ".join(_xml_comment(warn)), 1)
                    if not name.endswith(".yaml") else "".join(f"# {w}\n" for w in warn) + text)
        paths.append(atomic_write(folder / name, text))
    return tuple(paths)


# ------------------------------------------------------------------------------------------ --nominal
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


def _numbers(text: str) -> list[float]:
    return [float(x) for x in re.findall(_NUMBER, text)]


def parse_rotation(text: str, *, what: str = "--nominal") -> np.ndarray:
    """A rotation matrix from a person's text.

    Accepted: ``identity`` (or ``I``); ``ANGLE deg|rad about (X, Y, Z)`` (any axis, normalised); a matrix as
    9 numbers row by row (brackets, commas or spaces: ``[[0,-1,0],[-1,0,0],[0,0,-1]]``), orthonormal to 1e-3
    (rounded entries such as 0.7071 are projected onto the nearest rotation); ``rpy R, P, Y deg|rad``
    (``R = Rz(Y) Ry(P) Rx(R)``); ``xyzw X, Y, Z, W`` or ``wxyz W, X, Y, Z`` (a quaternion, normalised).

    Raises
    ------
    InputError
        Text of none of these forms, a zero axis or quaternion, a matrix that is not a rotation (not orthonormal,
        or a reflection).
    """
    from scipy.spatial.transform import Rotation

    from ..lie import exp, nearest_rotation

    t = str(text).strip()
    low = t.lower()
    forms = ("expected 'identity', 'ANGLE deg about (X, Y, Z)', 9 matrix entries row by row, "
             "'rpy R, P, Y deg' or 'xyzw X, Y, Z, W' / 'wxyz W, X, Y, Z'")
    if low in ("identity", "i", "eye"):
        return np.eye(3)
    m = re.fullmatch(rf"\s*({_NUMBER})\s*(deg|degrees?|rad|radians?)?\s*(?:about|around)\s*(.*)", low)
    if m:
        angle = float(m.group(1))
        angle = angle if (m.group(2) or "deg").startswith("rad") else np.deg2rad(angle)
        axis = np.array(_numbers(m.group(3)))
        if axis.size != 3 or not np.linalg.norm(axis) > 0:
            raise InputError(f"{what}: expected a non-zero axis of 3 numbers after 'about', got {m.group(3)!r}")
        return exp(angle * axis / np.linalg.norm(axis))
    if low.startswith("rpy"):
        v = _numbers(low[3:])
        if len(v) != 3:
            raise InputError(f"{what}: expected 'rpy R, P, Y' with 3 angles, got {t!r}")
        v = np.array(v) if "rad" in low else np.deg2rad(v)
        return Rotation.from_euler("xyz", v).as_matrix()
    if low.startswith(("xyzw", "wxyz")):
        q = _numbers(low[4:])
        if len(q) != 4 or not np.linalg.norm(q) > 0:
            raise InputError(f"{what}: expected 4 quaternion components after {low[:4]!r}, got {t!r}")
        q = q if low.startswith("xyzw") else q[1:] + q[:1]
        return Rotation.from_quat(q).as_matrix()
    v = _numbers(t)
    if len(v) == 9 and not re.search(r"[a-df-z]", low):
        M = np.array(v).reshape(3, 3)
        if np.abs(M @ M.T - np.eye(3)).max() > 1e-3:
            raise InputError(f"{what}: expected a rotation matrix (orthonormal rows), got {M.tolist()}")
        if np.linalg.det(M) < 0:
            raise InputError(f"{what}: expected a rotation (determinant +1), got a reflection {M.tolist()}")
        return nearest_rotation(M)
    raise InputError(f"{what}: {forms}; got {t!r}")


def parse_nominals(text: str, n_gyros: int, *, what: str = "--nominal") -> np.ndarray:
    """``(n_gyros, 3, 3)`` nominal rotations into gyro 1's frame from ``text``: one rotation for every gyro but the
    reference, or one per gyro 2..N, separated by ``;`` (each by :func:`parse_rotation`); gyro 1's is the identity.

    Raises
    ------
    InputError
        Another number of rotations, or one :func:`parse_rotation` refuses.
    """
    parts = [p for p in str(text).split(";")]
    if len(parts) not in (1, n_gyros - 1):
        raise InputError(f"{what}: expected one rotation for every gyro or one per gyro 2..{n_gyros} "
                         f"({n_gyros - 1}) separated by ';', got {len(parts)}")
    Rs = [parse_rotation(p, what=what if len(parts) == 1 else f"{what} (gyro {k + 2})") for k, p in enumerate(parts)]
    Rs = Rs * (n_gyros - 1) if len(Rs) == 1 else Rs
    return np.stack([np.eye(3)] + Rs)
