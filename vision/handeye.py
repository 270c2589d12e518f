"""Hand-eye calibration: where the camera sits on the robot (eye-in-hand) or in the cell (eye-to-hand).

Frames and transforms: ``T_a_b`` is a (4, 4) homogeneous transform with ``X_a = T_a_b @ X_b``
(translation [m]). The robot reports ``T_base_flange`` per view; the camera sees the board
as ``T_cam_board`` (solvePnP).

* **eye-in-hand** (camera on the flange, board fixed in the cell): the unknown is
  ``X = T_flange_cam``; ``T_base_flange_i @ X @ T_cam_board_i = T_base_board`` for every view.
* **eye-to-hand** (camera fixed, board held by the flange): the unknown is
  ``X = T_base_cam``; ``inv(T_base_flange_i) @ X @ T_cam_board_i = T_flange_board``.

Both are ``A X = X B`` over pairs of views (``A = inv(F_j) F_i``, ``B = C_j inv(C_i)`` with
``F`` the flange poses, inverted for eye-to-hand, and ``C`` the board poses). The closed form is
Park & Martin (1994): the rotation from the log maps, ``R_X = (M^T M)^(-1/2) M^T`` with
``M = sum beta alpha^T`` (alpha, beta the rotation vectors of A, B), then the translation by
linear least squares on ``(R_A - I) t_X = R_X t_B - t_A``. A Gauss-Newton refinement
(:func:`scipy.optimize.least_squares`) then minimises, over X and the constant board pose, the
per-view disagreement in millimetres and degrees; the closed form is its starting point.
"""

from __future__ import annotations

import csv as csvlib
import logging
from dataclasses import dataclass
from itertools import combinations

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from factory.core.errors import VisionError, shown
from factory.core.yamlfile import load_yaml
from vision.calibrate import Detection
from vision.camera import CameraModel

log = logging.getLogger(__name__)

#: Modes :func:`calibrate_handeye` accepts.
MODES = ("eye-in-hand", "eye-to-hand")
#: Fewest views a hand-eye calibration accepts (two motions with non-parallel axes need 3 poses;
#: fewer than 5 is rarely well conditioned, but the conditioning check below says so itself).
MIN_VIEWS = 3
#: Smallest relative rotation of a pair of views used in the closed form [rad]: pairs that barely
#: rotate carry no information on the rotation axis and amplify noise into the translation.
MIN_PAIR_ROTATION = np.radians(2.0)
#: Weight of rotation residuals against translation residuals in the refinement [m/rad]: about
#: the ratio of typical per-view position noise (0.3 mm) to orientation noise (0.05 deg ~ 0.9 mrad)
#: of robot and solvePnP poses, so each term counts by what it knows.
ROTATION_WEIGHT = 0.3


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


def make_transform(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """``(4, 4)`` transform from a (3, 3) rotation matrix or (3,) rotation vector [rad] and a
    (3,) translation [m]."""
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape == (3,):
        r = Rotation.from_rotvec(r).as_matrix()
    t = np.eye(4)
    t[:3, :3] = r
    t[:3, 3] = np.asarray(translation, dtype=np.float64).reshape(3)
    return t


def invert(t: np.ndarray) -> np.ndarray:
    """Inverse of a rigid ``(4, 4)`` transform."""
    r, p = t[:3, :3], t[:3, 3]
    out = np.eye(4)
    out[:3, :3] = r.T
    out[:3, 3] = -r.T @ p
    return out


def _check_poses(poses: np.ndarray, what: str) -> np.ndarray:
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (4, 4) or not np.isfinite(p).all():
        raise VisionError(f"{what} must be finite (n, 4, 4) transforms, got shape {p.shape}")
    r = p[:, :3, :3]
    bad = np.abs(np.einsum("nij,nkj->nik", r, r) - np.eye(3)).max(axis=(1, 2)) > 1e-6
    bad |= np.linalg.det(r) < 0
    if bad.any():
        raise VisionError(f"{what} #{int(np.argmax(bad))} is not a rigid transform (rotation not orthonormal)")
    return p


@dataclass(frozen=True)
class HandEyeResult:
    """A hand-eye calibration.

    Attributes
    ----------
    mode : str
        ``"eye-in-hand"`` or ``"eye-to-hand"``.
    transform : (4, 4) float
        Eye-in-hand: ``T_flange_cam``; eye-to-hand: ``T_base_cam`` (translation [m]).
    board : (4, 4) float
        The other constant: eye-in-hand ``T_base_board``, eye-to-hand ``T_flange_board`` [m].
    closed_form : (4, 4) float
        Park-Martin estimate of ``transform`` before refinement [m].
    translation_residuals : (n,) float
        Per view, distance between the board position this view implies and the fitted one [m].
    rotation_residuals : (n,) float
        Per view, angle between the board orientation this view implies and the fitted one [rad].
    condition : float
        Ratio of smallest to largest singular value of the Park-Martin matrix M (0 = degenerate:
        all rotation axes parallel; above ~0.1 is well spread).
    """

    mode: str
    transform: np.ndarray
    board: np.ndarray
    closed_form: np.ndarray
    translation_residuals: np.ndarray
    rotation_residuals: np.ndarray
    condition: float

    @property
    def translation_rms(self) -> float:
        """RMS of :attr:`translation_residuals` [m]."""
        return float(np.sqrt(np.mean(self.translation_residuals ** 2)))

    @property
    def rotation_rms(self) -> float:
        """RMS of :attr:`rotation_residuals` [rad]."""
        return float(np.sqrt(np.mean(self.rotation_residuals ** 2)))


def park_martin(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """Closed-form solution of ``A_k X = X B_k`` (Park & Martin 1994).

    Parameters
    ----------
    a, b : (m, 4, 4) float
        Relative motions (translation [m]), m >= 2 with non-parallel rotation axes.

    Returns
    -------
    x : (4, 4) float
        The transform X [m].
    condition : float
        Smallest over largest singular value of ``M`` (unitless; 0 when degenerate).

    Raises
    ------
    VisionError
        The rotation axes of the motions are (nearly) parallel: X's rotation is not determined.
    """
    alpha = Rotation.from_matrix(a[:, :3, :3]).as_rotvec()
    beta = Rotation.from_matrix(b[:, :3, :3]).as_rotvec()
    m = np.einsum("ni,nj->ij", beta, alpha)
    s = np.linalg.svd(m, compute_uv=False)
    condition = float(s[-1] / s[0]) if s[0] > 0 else 0.0
    if condition < 1e-3:
        raise VisionError("the robot poses rotate about (nearly) parallel axes only: tilt the flange about "
                          "at least two different axes between views")
    # (M^T M)^(-1/2) M^T through the eigen-decomposition of the symmetric M^T M.
    w, v = np.linalg.eigh(m.T @ m)
    r = v @ np.diag(1.0 / np.sqrt(w)) @ v.T @ m.T
    u, _, vt = np.linalg.svd(r)  # project onto SO(3): noise leaves it slightly off
    r = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    lhs = (a[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (np.einsum("ij,nj->ni", r, b[:, :3, 3]) - a[:, :3, 3]).reshape(-1)
    t, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)
    return make_transform(r, t), condition


def _pairs(f: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Relative motions ``A = inv(F_j) F_i``, ``B = C_j inv(C_i)`` of every pair that rotates enough."""
    a, b = [], []
    for i, j in combinations(range(len(f)), 2):
        ai = invert(f[j]) @ f[i]
        if np.linalg.norm(Rotation.from_matrix(ai[:3, :3]).as_rotvec()) < MIN_PAIR_ROTATION:
            continue
        a.append(ai)
        b.append(c[j] @ invert(c[i]))
    return np.array(a).reshape(-1, 4, 4), np.array(b).reshape(-1, 4, 4)


def _vec(t: np.ndarray) -> np.ndarray:
    return np.r_[Rotation.from_matrix(t[:3, :3]).as_rotvec(), t[:3, 3]]


def _mat(v: np.ndarray) -> np.ndarray:
    return make_transform(v[:3], v[3:])


def _chain(f: np.ndarray, c: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``F_i @ X @ C_i`` for every view: the board pose each view implies."""
    return np.einsum("nij,jk,nkl->nil", f, x, c)


def calibrate_handeye(flange_poses: np.ndarray, board_poses: np.ndarray, mode: str = "eye-in-hand",
                      *, refine: bool = True) -> HandEyeResult:
    """Camera-to-flange (eye-in-hand) or camera-to-base (eye-to-hand) transform.

    Parameters
    ----------
    flange_poses : (n, 4, 4) float
        ``T_base_flange`` of each view as the robot reports it (translation [m]).
    board_poses : (n, 4, 4) float
        ``T_cam_board`` of the same views (e.g. :func:`board_pose`) [m].
    mode : str
        ``"eye-in-hand"`` or ``"eye-to-hand"``.
    refine : bool
        Refine the Park-Martin closed form by least squares over X and the board pose.

    Raises
    ------
    VisionError
        Unknown mode, mismatched or malformed inputs, fewer than :data:`MIN_VIEWS` views, or
        motions that do not determine the rotation (parallel axes).
    """
    if mode not in MODES:
        raise VisionError(f"unknown hand-eye mode {shown(mode)}; use {' or '.join(MODES)}", source="--mode")
    f = _check_poses(flange_poses, "flange pose")
    c = _check_poses(board_poses, "board pose")
    if len(f) != len(c):
        raise VisionError(f"{len(f)} flange poses but {len(c)} board poses")
    if len(f) < MIN_VIEWS:
        raise VisionError(f"hand-eye calibration needs at least {MIN_VIEWS} views, got {len(f)}")
    if mode == "eye-to-hand":
        f = np.array([invert(t) for t in f])
    a, b = _pairs(f, c)
    if len(a) < 2:
        raise VisionError(f"fewer than two pairs of views rotate by {np.degrees(MIN_PAIR_ROTATION):.0f} deg or "
                          "more: move the flange through larger rotations")
    x0, condition = park_martin(a, b)
    z0 = _mean_pose(_chain(f, c, x0))
    x, z = x0, z0
    if refine:
        def residuals(p: np.ndarray) -> np.ndarray:
            implied = _chain(f, c, _mat(p[:6]))
            return _pose_errors(implied, _mat(p[6:]), weighted=True).reshape(-1)

        sol = least_squares(residuals, np.r_[_vec(x0), _vec(z0)], method="lm", x_scale="jac")
        x, z = _mat(sol.x[:6]), _mat(sol.x[6:])
    errs = _pose_errors(_chain(f, c, x), z, weighted=False)
    return HandEyeResult(mode=mode, transform=_frozen(x), board=_frozen(z), closed_form=_frozen(x0),
                         translation_residuals=_frozen(np.linalg.norm(errs[:, 3:], axis=1)),
                         rotation_residuals=_frozen(np.linalg.norm(errs[:, :3], axis=1)),
                         condition=condition)


def _pose_errors(implied: np.ndarray, z: np.ndarray, *, weighted: bool) -> np.ndarray:
    """``(n, 6)``: rotation vector of ``inv(Z) @ implied_i`` [rad] (times :data:`ROTATION_WEIGHT`
    when ``weighted``) and the position difference [m]."""
    rot = Rotation.from_matrix(np.einsum("ji,njk->nik", z[:3, :3], implied[:, :3, :3])).as_rotvec()
    if weighted:
        rot = rot * ROTATION_WEIGHT
    return np.hstack([rot, implied[:, :3, 3] - z[:3, 3]])


def _mean_pose(poses: np.ndarray) -> np.ndarray:
    """Chordal mean rotation and mean translation of ``(n, 4, 4)`` poses."""
    r = Rotation.from_matrix(poses[:, :3, :3]).mean().as_matrix()
    return make_transform(r, poses[:, :3, 3].mean(axis=0))


def board_pose(detection: Detection, camera: CameraModel) -> tuple[np.ndarray, float]:
    """``T_cam_board`` of one detected view by solvePnP with the calibrated camera.

    IPPE (exact for planar targets) starts a Levenberg-Marquardt refinement of the
    reprojection error.

    Returns
    -------
    pose : (4, 4) float
        Board-to-camera transform (translation [m]).
    rms : float
        RMS reprojection error of the corners [px].

    Raises
    ------
    VisionError
        (``source`` = the view) Fewer than 4 corners, or solvePnP fails.
    """
    obj = np.ascontiguousarray(detection.object_points, dtype=np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(detection.image_points, dtype=np.float64).reshape(-1, 1, 2)
    if len(obj) < 4:
        raise VisionError(f"pose needs at least 4 corners, got {len(obj)}", source=detection.name)
    try:
        ok, rvec, tvec = cv2.solvePnP(obj, img, camera.K, camera.dist, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            raise VisionError("solvePnP found no board pose", source=detection.name)
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, camera.K, camera.dist, rvec, tvec)
    except cv2.error as e:
        raise VisionError(f"solvePnP failed: {str(e).strip().splitlines()[-1]}", source=detection.name) from None
    rvec, tvec = rvec.reshape(3), tvec.reshape(3)
    res = detection.image_points - camera.project(detection.object_points, rvec, tvec)
    return make_transform(rvec, tvec), float(np.sqrt(np.mean(np.sum(res ** 2, axis=1))))


def pose_from_xyz_rotation(xyz: np.ndarray, *, rotvec: np.ndarray | None = None,
                           quat_xyzw: np.ndarray | None = None) -> np.ndarray:
    """``(4, 4)`` transform from a position [m] and a rotation vector [rad] or a unit quaternion
    ``(x, y, z, w)`` (ROS order; normalised here, must not be zero)."""
    if (rotvec is None) == (quat_xyzw is None):
        raise VisionError("give a rotation vector or a quaternion, not both or neither")
    if quat_xyzw is not None:
        q = np.asarray(quat_xyzw, dtype=np.float64).reshape(4)
        n = np.linalg.norm(q)
        if not np.isfinite(n) or n < 1e-9:
            raise VisionError(f"quaternion {q.tolist()} has no length")
        r = Rotation.from_quat(q / n).as_matrix()
    else:
        r = Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64).reshape(3)).as_matrix()
    return make_transform(r, xyz)


def transform_to_xyz_quat(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position [m] and unit quaternion ``(x, y, z, w)`` (w >= 0) of a ``(4, 4)`` transform."""
    q = Rotation.from_matrix(np.asarray(t)[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return np.asarray(t)[:3, 3].copy(), q


#: ``format`` value of the hand-eye result file.
HANDEYE_FORMAT = "factory.handeye/1"
#: Frames the result transform maps between, per mode: (parent, child).
FRAMES = {"eye-in-hand": ("flange", "camera"), "eye-to-hand": ("base", "camera")}
#: Frames of the board pose in the result file, per mode: (parent, child).
BOARD_FRAMES = {"eye-in-hand": ("base", "board"), "eye-to-hand": ("flange", "board")}


def parse_robot_poses(text: str, *, source: str = "poses", csv: bool = False) -> dict[str, np.ndarray]:
    """Flange poses ``T_base_flange`` per image file name, from the robot pose file.

    YAML::

        poses:
          view00.png: {xyz: [0.40, 0.10, 0.30], rotvec: [0.0, 3.1416, 0.0]}   # [m], [rad]
          view01.png: {xyz: [0.42, 0.05, 0.31], quat: [0.0, 1.0, 0.0, 0.0]}   # x y z w

    CSV (``csv=True``), a header row then one row per image, either rotation::

        image,x,y,z,rx,ry,rz            # rotation vector [rad] (UR controllers report this)
        image,x,y,z,qx,qy,qz,qw         # unit quaternion, ROS order

    Positions are of the flange in the robot base frame [m].

    Raises
    ------
    VisionError
        (``source``, naming the image or row) Not YAML/CSV, a field missing, not numbers, both
        or neither rotation, a zero quaternion, an image named twice, or no poses at all.
    """
    poses: dict[str, np.ndarray] = {}

    def add(name: object, xyz: object, rotvec: object = None, quat: object = None, where: str = "") -> None:
        name = str(name).strip()
        if not name:
            raise VisionError(f"{where}: empty image name", source=source)
        if name in poses:
            raise VisionError(f"image {shown(name)} has two poses", source=source)
        try:
            p = np.array(xyz, dtype=np.float64)
            rv = None if rotvec is None else np.array(rotvec, dtype=np.float64)
            q = None if quat is None else np.array(quat, dtype=np.float64)
        except (TypeError, ValueError):
            raise VisionError(f"{name}: xyz and rotation must be numbers", source=source) from None
        if p.shape != (3,) or (rv is not None and rv.shape != (3,)) or (q is not None and q.shape != (4,)):
            raise VisionError(f"{name}: need xyz (3 numbers [m]) and rotvec (3 [rad]) or quat (4, x y z w)",
                              source=source)
        if not all(np.isfinite(v).all() for v in (p, rv, q) if v is not None):
            raise VisionError(f"{name}: pose values must be finite", source=source)
        try:
            poses[name] = pose_from_xyz_rotation(p, rotvec=rv, quat_xyzw=q)
        except VisionError as e:
            raise VisionError(f"{name}: {e.message}", source=source) from None

    if csv:
        rows = [r for r in csvlib.reader(text.splitlines()) if r and any(c.strip() for c in r)]
        if not rows:
            raise VisionError("empty pose file", source=source)
        head = [c.strip().lower() for c in rows[0]]
        rot_cols = {("rx", "ry", "rz"): "rotvec", ("qx", "qy", "qz", "qw"): "quat"}
        kind = None
        for cols, k in rot_cols.items():
            if head[:4] == ["image", "x", "y", "z"] and tuple(head[4:]) == cols:
                kind = k
        if kind is None:
            raise VisionError("CSV header must be image,x,y,z,rx,ry,rz or image,x,y,z,qx,qy,qz,qw, got "
                              + ",".join(head), source=source)
        for i, row in enumerate(rows[1:], start=2):
            if len(row) != len(head):
                raise VisionError(f"line {i}: {len(row)} fields, the header has {len(head)}", source=source)
            try:
                values = [float(v) for v in row[1:]]
            except ValueError:
                raise VisionError(f"line {i}: pose values must be numbers", source=source) from None
            add(row[0], values[:3], **{kind: values[3:]}, where=f"line {i}")
    else:
        doc = load_yaml(text, source=source, error=VisionError)
        if not isinstance(doc, dict) or not isinstance(doc.get("poses"), dict):
            raise VisionError("expected a mapping 'poses: {IMAGE: {xyz: [...], rotvec|quat: [...]}}'",
                              source=source)
        for name, entry in doc["poses"].items():
            if not isinstance(entry, dict) or "xyz" not in entry or ("rotvec" in entry) == ("quat" in entry):
                raise VisionError(f"{name}: need xyz and exactly one of rotvec or quat", source=source)
            add(name, entry["xyz"], entry.get("rotvec"), entry.get("quat"), where=str(name))
    if not poses:
        raise VisionError("no poses in file", source=source)
    return poses


def _pose_doc(t: np.ndarray, parent: str, child: str) -> dict:
    xyz, q = transform_to_xyz_quat(t)
    return {"parent_frame": parent, "child_frame": child,
            "matrix": [[float(v) for v in row] for row in np.asarray(t)],
            "xyz": [float(v) for v in xyz], "quaternion_xyzw": [float(v) for v in q]}


def handeye_document(result: HandEyeResult, views: list[str], reprojection_px: list[float],
                     without_board: list[str] = ()) -> dict:
    """The hand-eye result file's content (``format: factory.handeye/1``) as a YAML-ready dict.

    ``transform`` is ``T_parent_child`` (``X_parent = matrix @ X_child``) [m]; residuals are per view
    [m], [rad] and the corners' reprojection error [px].
    """
    parent, child = FRAMES[result.mode]
    bp, bc = BOARD_FRAMES[result.mode]
    return {
        "format": HANDEYE_FORMAT,
        "mode": result.mode,
        "transform": _pose_doc(result.transform, parent, child),
        "board": _pose_doc(result.board, bp, bc),
        "residuals": {
            "translation_rms_m": result.translation_rms,
            "rotation_rms_rad": result.rotation_rms,
            "condition": result.condition,
            "views": [{"image": v, "translation_m": float(t), "rotation_rad": float(r), "reprojection_px": float(p)}
                      for v, t, r, p in zip(views, result.translation_residuals, result.rotation_residuals,
                                            reprojection_px)],
        },
        "views_without_board": list(without_board),
    }


@dataclass(frozen=True)
class Extrinsics:
    """A hand-eye result file read back.

    Attributes
    ----------
    mode : str
    transform : (4, 4) float
        ``T_flange_cam`` (eye-in-hand) or ``T_base_cam`` (eye-to-hand) [m].
    tray_z : float or None
        Height of the tray plane in the base frame [m], when the file carries ``tray_z``.
    """

    mode: str
    transform: np.ndarray
    tray_z: float | None = None

    def base_camera(self, flange: np.ndarray | None = None) -> np.ndarray:
        """``T_base_cam`` [m]; eye-in-hand needs the flange pose ``T_base_flange`` of the picture.

        Raises
        ------
        VisionError
            Eye-in-hand without a flange pose.
        """
        if self.mode == "eye-to-hand":
            return np.array(self.transform)
        if flange is None:
            raise VisionError("eye-in-hand extrinsics: the flange pose of the picture is needed (--flange)")
        return np.asarray(flange, dtype=np.float64) @ self.transform


def read_extrinsics(text: str, *, source: str = "extrinsics") -> Extrinsics:
    """Read a ``factory.handeye/1`` YAML text (see :func:`handeye_document`); ``tray_z`` [m] optional.

    Raises
    ------
    VisionError
        (``source``) Not YAML, not a hand-eye file, or a transform that is not rigid.
    """
    doc = load_yaml(text, source=source, error=VisionError)
    if not isinstance(doc, dict) or doc.get("format") != HANDEYE_FORMAT:
        raise VisionError(f"not a hand-eye file (format: {HANDEYE_FORMAT})", source=source)
    mode = doc.get("mode")
    if mode not in MODES:
        raise VisionError(f"field 'mode' must be one of {', '.join(MODES)}, got {shown(mode)}", source=source)
    try:
        t = np.array(doc["transform"]["matrix"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise VisionError("field 'transform.matrix' must be a 4x4 matrix of numbers", source=source) from None
    try:
        t = _check_poses(t.reshape(1, 4, 4) if t.shape == (4, 4) else t, "transform")[0]
    except VisionError as e:
        raise VisionError(f"field 'transform.matrix': {e.message}", source=source) from None
    tray = doc.get("tray_z")
    if tray is not None and (isinstance(tray, bool) or not isinstance(tray, (int, float)) or not np.isfinite(tray)):
        raise VisionError(f"field 'tray_z' must be a height in metres, got {shown(tray)}", source=source)
    return Extrinsics(mode=mode, transform=_frozen(t), tray_z=None if tray is None else float(tray))
