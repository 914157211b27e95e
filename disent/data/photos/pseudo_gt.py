"""Pseudo ground truth for real photos, as the paper builds it for CelebA (Sec. 4.2).

One photo goes through five steps, each a function here:

1. :func:`decode_image`   bytes -> 8-bit RGB, converting what can be converted
   (grayscale, alpha, 16-bit, CMYK, palette, EXIF rotation) and refusing the rest
   with a :class:`Skip` that names the reason;
2. :class:`LandmarkDetector`  dlib's HOG face detector + the 68-point iBUG shape predictor;
3. :func:`align`          similarity transform of the landmarks onto the face model's own
   frontal landmarks, so a photo is framed like a SynthFaces image at the training resolution;
4. :func:`fit_landmarks`  the face model (pose, identity, expression) fitted to the 68
   landmarks by regularized least squares (``scipy.optimize.least_squares``);
5. :func:`maps_from_fit`  the fitted mesh rasterized to ``normal_pseudo``, ``mask_pseudo``,
   ``uv_pseudo``, ``normal_uv_pseudo``; then ``sh_pseudo`` = L-hat with a constant albedo
   (:func:`disent.render.fit_sh`), by SynthFaces' own code, so both data sets share it, on the crop's
   pixels decoded from sRGB to linear radiance (:func:`crop_pixels`), as every model reads them.

:func:`prepare` runs the steps over many files with worker processes and a progress bar,
and caches each result (or the reason it was skipped) under the file's content hash, so a
second pass only reads the cache and an interrupted pass keeps what it finished.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import io
import itertools
import json
import logging
import os
from collections import Counter
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from disent.storage import atomic_write

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".webp", ".tif", ".tiff", ".ppm", ".pgm", ".pbm", ".pnm")
# iBUG 68-point layout: contour 0-16, brows 17-26, nose 27-35, eyes 36-47, mouth 48-67.
CONTOUR = slice(0, 17)
INNER = np.arange(17, 68)  # the landmarks that do not slide along the silhouette
CACHE_VERSION = 5  # 5: sh_pseudo fitted on the linear (sRGB-decoded) crop


@dataclass(frozen=True)
class PseudoGTSettings:
    """Every knob of the pipeline; all of them enter the cache key."""

    resolution: int = 64
    predictor: str | None = None  # 68-point shape predictor .dat; None: face_recognition_models' file
    min_side: int = 16  # smaller images are skipped ("too small")
    detect_side: int = 320  # images whose short side is smaller are upscaled for detection,
    detect_max_side: int = 800  # and those whose short side is larger downscaled (speed)
    upsample: int = 1  # dlib's pyramid upsampling for the detector (finds smaller faces)
    multiple_faces: str = "keep"  # several faces: "keep" the one ranked ``face`` by size; "skip" the image
    face: int = 0  # rank by size (0: the largest, ties broken by detection score) of the face kept
    contour_weight: float = 0.5  # weight of the 17 jaw-line landmarks in the fit (they slide with pose)
    lambda_identity: float = 1.0  # Gaussian prior weights on the model coefficients (unit-variance units)
    lambda_expression: float = 1.0
    landmark_sigma: float = 0.02  # landmark noise std, in units of the crop width
    max_nfev: int = 200
    n_identity: int = 4  # identity components fitted: SynthFaces' coarse fit (synth.PSEUDO_COMPONENTS)

    def key(self) -> str:
        """A short hash of the settings, the predictor file and the face model, naming the cache."""
        d = dataclasses.asdict(self)
        try:
            d["predictor"] = _file_identity(self.predictor_path())
        except FileNotFoundError:
            d["predictor"] = None
        d["version"], d["face_model"] = CACHE_VERSION, _face_model_identity()
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]

    def predictor_path(self) -> str:
        return self.predictor or default_predictor_path()


class Skip(Exception):
    """An image that cannot be used; ``reason`` is a short key the summary counts."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason, self.detail = reason, detail


# ----------------------------------------------------------------------------- 1. decoding
def decode_image(data: bytes, min_side: int = 16) -> tuple[np.ndarray, list[str]]:
    """Decode an encoded image to ``uint8 [H, W, 3]`` RGB, and the conversions applied.

    Converted: grayscale and bilevel (replicated to RGB), alpha (composited over white),
    16-bit (scaled to 8 bits), CMYK and other colour spaces, palettes, EXIF orientation.
    Skipped (:class:`Skip`): empty file, not an image, truncated or corrupt data,
    an image with a side under ``min_side`` pixels.
    """
    from PIL import Image, ImageOps, UnidentifiedImageError

    if len(data) == 0:
        raise Skip("empty file")
    try:
        img = Image.open(io.BytesIO(data))
    except UnidentifiedImageError:
        raise Skip("not an image", f"{len(data)} bytes, no known image header") from None
    except Image.DecompressionBombError as e:
        raise Skip("too large", str(e)) from None
    try:
        img.load()
    except Exception as e:  # PIL raises OSError, SyntaxError, zlib/struct errors on cut data
        raise Skip("truncated or corrupt", f"{img.format}: {e}") from None
    notes = []
    if img.format == "PNG" and data[24] == 16 and img.mode == "RGB":  # IHDR bit depth; PIL keeps the high byte
        notes.append("16-bit->8-bit")
    if min(img.size) < min_side:
        raise Skip("too small", f"{img.size[0]}x{img.size[1]} < {min_side} px")
    if img.getexif().get(0x0112, 1) != 1:  # EXIF orientation: turn the pixels upright
        img = ImageOps.exif_transpose(img)
        notes.append("EXIF rotation")
    mode = img.mode
    if mode in ("I;16", "I;16B", "I;16L", "I", "F"):  # high bit depth gray: scale, don't clip
        a = np.asarray(img).astype(np.float64)
        top = 65535.0 if mode.startswith("I;16") or a.max() > 255 else 255.0
        if mode == "F":
            top = max(1.0, float(a.max()))
        notes.append(f"{mode}->8-bit")
        a = np.clip(np.rint(a * (255.0 / top)), 0, 255).astype(np.uint8)
        return np.repeat(a[..., None], 3, 2), notes
    if mode == "P":
        img = img.convert("RGBA" if "transparency" in img.info else "RGB")
        notes.append("palette->RGB")
        mode = img.mode
    if mode in ("RGBA", "LA", "PA", "RGBa", "La"):
        rgba = np.asarray(img.convert("RGBA")).astype(np.float64) / 255.0
        a = rgba[..., 3:]
        rgb = rgba[..., :3] * a + (1.0 - a)  # over white
        notes.append(f"{mode}->RGB over white")
        return np.clip(np.rint(rgb * 255), 0, 255).astype(np.uint8), notes
    if mode != "RGB":
        notes.append(f"{mode}->RGB")
        img = img.convert("RGB")
    return np.asarray(img, dtype=np.uint8).copy(), notes


# ----------------------------------------------------------------------------- 2. landmarks
def default_predictor_path() -> str:
    """The 68-point predictor shipped by ``face_recognition_models`` (``pip install -e ".[photos]"``),
    else Debian's ``libdlib-data`` copy.  The package's ``__init__`` needs the removed
    ``pkg_resources``, so its folder is located without importing it."""
    import importlib.util

    candidates = []
    spec = importlib.util.find_spec("face_recognition_models")
    if spec is not None and spec.submodule_search_locations:
        for loc in spec.submodule_search_locations:
            candidates.append(Path(loc) / "models" / "shape_predictor_68_face_landmarks.dat")
    candidates.append(Path("/usr/share/dlib/shape_predictor_68_face_landmarks.dat"))
    for c in candidates:
        if c.is_file():
            return str(c)
    raise FileNotFoundError(
        "no 68-point shape predictor found; install the extra with "
        '`pip install -e ".[photos]"` or set data.predictor=PATH '
        f"(looked in {[str(c) for c in candidates]})"
    )


def _file_identity(path: str) -> str:
    st = os.stat(path)
    return f"{Path(path).name}:{st.st_size}"


@functools.lru_cache(maxsize=1)
def _face_model_identity() -> str:
    """A hash of the face model's arrays and SynthFaces' framing: a changed model invalidates the cache."""
    from disent.data.synth import scenes as synth
    from disent.data.synth.face_model import face_model

    m, h = face_model(), hashlib.sha256()
    for t in (m.mean, m.identity, m.expression, m.faces, m.uv, m.landmarks, m.face_region):
        h.update(t.detach().cpu().numpy().tobytes())
    h.update(repr((synth.SCALE_RANGE, synth.PSEUDO_GRID_STEP)).encode())
    return h.hexdigest()[:12]


class LandmarkDetector:
    """dlib face detection and 68 iBUG landmarks: ``rgb uint8 [H,W,3] -> (landmarks [68, 2], faces)``
    with landmarks as (x, y) pixels of ``rgb`` and ``faces`` every detection, largest first:
    ``{"score", "box": [left, top, right, bottom] in pixels of rgb, "upsample"}``.

    Images whose short side is under ``detect_side`` are upscaled (bicubic) first: dlib's
    HOG detector misses faces smaller than about 80 pixels; above ``detect_max_side`` they are
    downscaled, which costs no accuracy at crop resolution.  Where no face is found, the detector
    tries once more with one more level of pyramid upsampling (smaller and turned faces).  With
    several faces the one ranked ``face`` by size is kept (:func:`process` skips the image instead
    where ``multiple_faces="skip"``).
    """

    def __init__(self, settings: PseudoGTSettings):
        import dlib

        self.settings = settings
        self.detector = dlib.get_frontal_face_detector()
        self.predictor = dlib.shape_predictor(settings.predictor_path())

    def __call__(self, rgb: np.ndarray) -> tuple[np.ndarray, int]:
        from PIL import Image

        s, (h, w) = self.settings, rgb.shape[:2]
        scale = float(np.clip(min(h, w), s.detect_side, s.detect_max_side)) / min(h, w)
        work = rgb
        if scale != 1.0:
            size = (round(w * scale), round(h * scale))
            work = np.asarray(Image.fromarray(rgb).resize(size, Image.BICUBIC if scale > 1 else Image.LANCZOS))
            scale = np.array(size) / (w, h)
        for upsample in (s.upsample, s.upsample + 1):
            rects, scores, _ = self.detector.run(work, upsample, 0.0)
            if len(rects):
                break
        else:
            raise Skip("no face found", f"detector upsampling {s.upsample} and {s.upsample + 1}")
        order = sorted(range(len(rects)), key=lambda i: (-rects[i].area(), -scores[i]))
        if s.face >= len(order):
            raise Skip("no such face", f"face {s.face} asked, {len(order)} found")
        shape = self.predictor(work, rects[order[s.face]])
        pts = np.array([(p.x, p.y) for p in shape.parts()], dtype=np.float64)
        sx, sy = np.broadcast_to(scale, 2)
        to_rgb = lambda x, y: ((x + 0.5) / sx - 0.5, (y + 0.5) / sy - 0.5)  # noqa: E731  pixel centres at integers
        faces = [
            {
                "score": round(float(scores[i]), 3),
                "upsample": upsample,
                "box": [
                    round(float(v), 1)
                    for v in (*to_rgb(rects[i].left(), rects[i].top()), *to_rgb(rects[i].right(), rects[i].bottom()))
                ],
            }
            for i in order
        ]
        return (pts + 0.5) / scale - 0.5, faces


# ----------------------------------------------------------------------------- 3. alignment
def similarity_transform(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares similarity (Umeyama) mapping ``src [N,2]`` onto ``dst [N,2]``, as a 3x3 matrix."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.diag([1.0, d])
    R = U @ D @ Vt
    scale = (S * np.diag(D)).sum() / a.var(0).sum()
    M = np.eye(3)
    M[:2, :2] = scale * R
    M[:2, 2] = mu_d - scale * R @ mu_s
    return M


def align(rgb: np.ndarray, landmarks: np.ndarray, template: np.ndarray, resolution: int):
    """Crop ``rgb`` so that its landmarks land on ``template`` (``[68,2]`` pixels of a
    ``resolution``-square image), fitting a similarity on the non-contour landmarks.

    Returns ``(crop uint8 [R,R,3], landmarks in the crop [68,2], M 3x3 photo->crop)``.
    Downscaling is anti-aliased by a Gaussian prefilter; where the crop reaches past the photo
    it is filled with the photo's mean colour.
    """
    from PIL import Image
    from scipy import ndimage
    from skimage.transform import warp

    M = similarity_transform(landmarks[INNER], template[INNER])
    Mw, scale = M, np.sqrt(abs(np.linalg.det(M[:2, :2])))
    f = int(1.0 / scale // 2)
    if f >= 2:  # large photo: box-average f x f blocks first (pixel x' of the reduced image sits at f x' + (f-1)/2)
        rgb = np.asarray(Image.fromarray(rgb).reduce(f))
        Mw = M @ np.array([[f, 0, (f - 1) / 2], [0, f, (f - 1) / 2], [0, 0, 1.0]])
        scale *= f
    img = rgb.astype(np.float64) / 255.0
    if scale < 1.0:  # photo pixels per crop pixel = 1/scale
        sigma = 0.5 * np.sqrt(max(1.0 / scale**2 - 1.0, 0.0))
        img = ndimage.gaussian_filter(img, (sigma, sigma, 0))
    inv = np.linalg.inv(Mw)
    crop = warp(img, inv, output_shape=(resolution, resolution), order=1, mode="edge")
    inside = warp(np.ones(img.shape[:2]), inv, output_shape=(resolution, resolution), order=1, cval=0.0)[..., None]
    crop = crop * inside + img.mean((0, 1)) * (1 - inside)
    lm = landmarks @ M[:2, :2].T + M[:2, 2]
    return np.clip(np.rint(crop * 255), 0, 255).astype(np.uint8), lm, M


# ----------------------------------------------------------------------------- the face model, posed
class FaceModelFitter:
    """The project's face model (:mod:`disent.data.synth.face_model`) under a scaled-orthographic camera.

    Parameters ``p = [yaw, pitch, roll (radians), log scale, tx, ty, alpha_1..K, smile, open]``;
    ``R`` is :func:`disent.data.synth.raster.pose_matrix` of the angles (SynthFaces' ``pose``), and a
    model point ``X`` lands at crop pixel ``(col, row) = (s (R X)_x + tx, -s (R X)_y + ty)``
    (pixel centres at integers, row 0 at the top, as dlib and scikit-image count), so
    camera-frame normals keep the suite's convention (+x right, +y up, +z towards the camera).
    Scaled orthography is the usual camera of landmark fitting: at the distances of portraits,
    perspective changes landmark positions by less than dlib's own noise.
    """

    n_pose = 6

    def __init__(self, n_identity: int = 4):
        from disent.data.synth.face_model import EXPRESSIONS, face_model

        m = face_model()
        self.model, self.n_identity, self.n_expression = m, n_identity, len(EXPRESSIONS)
        idx = m.landmarks.numpy()
        self.lm_mean = m.mean.double().numpy()[idx]  # [68, 3]
        self.lm_basis = np.concatenate(
            [m.identity[:n_identity].double().numpy()[:, idx], m.expression.double().numpy()[:, idx]]
        )  # [K+2, 68, 3]

    def landmarks3d(self, p: np.ndarray) -> np.ndarray:
        return self.lm_mean + np.tensordot(p[self.n_pose :], self.lm_basis, 1)

    @staticmethod
    def rotation(p: np.ndarray) -> np.ndarray:
        import torch

        from disent.data.synth.raster import pose_matrix

        return pose_matrix(torch.tensor(np.degrees(p[None, :3]), dtype=torch.float64))[0].numpy()

    def project(self, p: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Model points ``[N, 3]`` -> (col, row, depth) ``[N, 3]``; depth grows towards the camera."""
        cam = points @ self.rotation(p).T * np.exp(p[3])
        return np.stack([cam[:, 0] + p[4], -cam[:, 1] + p[5], cam[:, 2]], 1)

    def project_landmarks(self, p: np.ndarray, resolution: int) -> np.ndarray:
        return self.project(p, self.landmarks3d(p))[:, :2]

    def bounds(self):
        lo = np.full(self.n_pose + self.n_identity + self.n_expression, -np.inf)
        hi = -lo
        lo[:3], hi[:3] = -np.pi / 2, np.pi / 2  # a face seen from the front half-space
        lo[-self.n_expression :], hi[-self.n_expression :] = 0.0, 1.0  # smile, open strengths
        return lo, hi

    @staticmethod
    def to_raster(p: np.ndarray, resolution: int) -> dict:
        """Pose (degrees), scale and shift of :func:`disent.data.synth.raster.to_camera` for ``p``:
        crop pixels -> normalised units x = (2 col + 1)/R - 1, y = 1 - (2 row + 1)/R."""
        R = resolution
        return {
            "pose": np.degrees(p[:3]),
            "scale": 2 * np.exp(p[3]) / R,
            "shift": np.array([(2 * p[4] + 1) / R - 1, 1 - (2 * p[5] + 1) / R]),
        }

    @staticmethod
    def raster_to_pixels(xy: np.ndarray, resolution: int) -> np.ndarray:
        """Normalised image units ``[..., 2]`` (x right, y up) -> crop pixels (col, row)."""
        xy = np.asarray(xy, dtype=np.float64)
        return np.stack([((xy[..., 0] + 1) * resolution - 1) / 2, ((1 - xy[..., 1]) * resolution - 1) / 2], -1)

    def synth_landmarks(self, scene: dict, resolution: int) -> np.ndarray:
        """The exact 68 landmarks ``[B, 68, 2]`` (pixels) of SynthFaces scenes (``SynthFaces.params``)."""
        from disent.data.synth.raster import to_camera

        m = self.model
        verts = m.shape(scene["alpha"], scene["expression"], scene.get("senior"))[:, m.landmarks]
        cam = to_camera(verts.double(), scene["pose"], scene["scale"], scene["shift"])
        return self.raster_to_pixels(cam[..., :2].numpy(), resolution)

    def from_raster(self, pose_deg, scale: float, shift, resolution: int) -> np.ndarray:
        """The inverse of :meth:`to_raster`, with mean identity and neutral expression."""
        R = resolution
        p = np.zeros(self.n_pose + self.n_identity + self.n_expression)
        p[:3], p[3] = np.radians(pose_deg), np.log(scale * R / 2)
        p[4:6] = ((shift[0] + 1) * R - 1) / 2, ((1 - shift[1]) * R - 1) / 2
        return p

    def template(self, resolution: int) -> np.ndarray:
        """The alignment target: a frontal mean face's landmarks framed as SynthFaces frames its
        faces on average (scale mid-range of ``synth.SCALE_RANGE``, shift (0, -0.02), see
        ``synth.scene_params``), so photos and synthetic images share the crop."""
        from disent.data.synth.scenes import SCALE_RANGE

        p = self.from_raster((0.0, 0.0, 0.0), float(np.mean(SCALE_RANGE)), (0.0, -0.02), resolution)
        return self.project_landmarks(p, resolution)

    def scene(self, p: np.ndarray, resolution: int) -> dict:
        """The fit ``p`` as the coarse-fit entries (``pseudo_*``, a batch of one) of SynthFaces' scene parameters,
        what :func:`disent.data.synth.scenes.render_pseudo` draws."""
        import torch

        K, cam = self.n_identity, self.to_raster(p, resolution)
        t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float32))[None]  # noqa: E731
        return {
            "pseudo_alpha": t(p[6 : 6 + K]),
            "pseudo_expression": t(p[6 + K :]),
            "pseudo_pose": t(cam["pose"]),
            "pseudo_scale": t(cam["scale"]),
            "pseudo_shift": t(cam["shift"]),
        }

    def render(self, p: np.ndarray, resolution: int, image: np.ndarray) -> dict:
        """The pseudo-GT maps ``[C, R, R]`` and ``sh_pseudo [3, 9]`` (numpy) of the fitted face over
        ``image [3, R, R]``, made by SynthFaces' own :func:`disent.data.synth.scenes.render_pseudo`
        (its coarse mesh, the face region as ``mask_pseudo``, L-hat with constant albedo)."""
        import torch

        from disent.data.synth.scenes import render_pseudo

        try:
            out = render_pseudo(
                torch.as_tensor(image, dtype=torch.float32)[None], self.scene(p, resolution), resolution
            )
        except ValueError as e:  # fit_sh: too few pixels or non-finite values
            raise Skip("fit failed", f"rendering/lighting: {e}") from None
        return {k: v[0].numpy() for k, v in out.items()}

    def initial_params(self, landmarks: np.ndarray, resolution: int) -> np.ndarray:
        """Frontal mean face placed on the landmarks by a similarity (scale, roll, shift)."""
        M = similarity_transform(self.lm_mean[INNER, :2] * [1.0, -1.0], landmarks[INNER])
        s = np.sqrt(abs(np.linalg.det(M[:2, :2])))
        roll = np.arctan2(-M[1, 0], M[0, 0])  # image rows run down: the in-plane angle flips sign
        p = np.zeros(self.n_pose + self.n_identity + self.n_expression)
        p[2], p[3], p[4:6] = roll, np.log(s), M[:2, 2]
        return p


@functools.lru_cache(maxsize=4)
def face_model_fitter(settings: PseudoGTSettings) -> FaceModelFitter:
    return FaceModelFitter(settings.n_identity)


def coarse_fit_scene(params: np.ndarray, resolution: int) -> dict:
    """A photo's coarse fit (its pseudo-GT's ``params``) as SynthFaces' coarse-fit scene parameters
    (:meth:`FaceModelFitter.scene`), the number of identity components read from its length."""
    from disent.data.synth.face_model import EXPRESSIONS

    params = np.asarray(params, dtype=np.float64)
    return FaceModelFitter(len(params) - FaceModelFitter.n_pose - len(EXPRESSIONS)).scene(params, resolution)


# ----------------------------------------------------------------------------- 4. model fit
def fit_landmarks(landmarks: np.ndarray, resolution: int, settings: PseudoGTSettings, model=None) -> dict:
    """Fit pose, identity and expression of the face model to 68 landmarks (crop pixels).

    MAP estimate with the model's Gaussian priors (coefficients in units of their std):
    minimize  sum_i w_i |P(x_i) - l_i|^2 / sigma^2 + lambda_id |alpha|^2 + lambda_exp |beta|^2
    over the camera pose (yaw, pitch, roll, scale, 2-D shift) and alpha, beta, where the
    jaw-line landmarks get weight ``contour_weight`` (they slide along the silhouette).
    Returns ``params`` (the model's parameter vector), the fitted 2-D ``landmarks`` and the
    unweighted RMS landmark distance ``residual_px``.
    """
    from scipy.optimize import least_squares

    model = model or face_model_fitter(settings)
    lm = np.asarray(landmarks, dtype=np.float64)
    sigma = settings.landmark_sigma * resolution
    w = np.ones(68)
    w[CONTOUR] = settings.contour_weight
    sw = np.sqrt(w)[:, None] / sigma
    reg = np.sqrt(
        np.concatenate(
            [
                np.full(model.n_identity, settings.lambda_identity),
                np.full(model.n_expression, settings.lambda_expression),
            ]
        )
    )

    def residuals(p):
        return np.concatenate([((model.project_landmarks(p, resolution) - lm) * sw).ravel(), reg * p[model.n_pose :]])

    p0 = model.initial_params(lm, resolution)
    sol = least_squares(residuals, p0, bounds=model.bounds(), method="trf", x_scale="jac", max_nfev=settings.max_nfev)
    fitted = model.project_landmarks(sol.x, resolution)
    if not np.all(np.isfinite(fitted)):
        raise Skip("fit failed", "non-finite landmark projection")
    return {
        "params": sol.x,
        "landmarks": fitted,
        "residual_px": float(np.sqrt(((fitted - lm) ** 2).sum(1).mean())),
        "nfev": sol.nfev,
    }


# ----------------------------------------------------------------------------- 5. rendering
def maps_from_fit(fit: dict, image: np.ndarray, model) -> dict:
    """The fitted face rasterized to the pseudo-GT maps, channels first, exactly as SynthFaces
    makes them: ``normal_pseudo [3,R,R]``, ``mask_pseudo [1,R,R]``, ``uv_pseudo [2,R,R]``,
    ``normal_uv_pseudo [3,R,R]``, and ``sh_pseudo [3,9]`` = L-hat of ``image [3,R,R]``."""
    maps = model.render(fit["params"], image.shape[-1], image)
    if float(maps["mask_pseudo"].sum()) < 16:
        raise Skip("fit failed", "the fitted face covers under 16 pixels of the crop")
    return maps


# ----------------------------------------------------------------------------- 6. one image, many images
def process(data: bytes, settings: PseudoGTSettings, detector: LandmarkDetector | None = None) -> dict:
    """The whole pipeline on one encoded image: a dict of numpy arrays (see :func:`prepare`)."""
    rgb, notes = decode_image(data, settings.min_side)
    landmarks, found = (detector or landmark_detector(settings))(rgb)
    n_faces = len(found) if isinstance(found, list) else int(found)
    if n_faces > 1 and settings.multiple_faces == "skip":
        raise Skip("several faces", f"{n_faces} detections")
    notes += face_notes(found, settings)
    faces = found if isinstance(found, list) else []
    table = np.array([[*f["box"], f["score"]] for f in faces], dtype=np.float32).reshape(-1, 5)
    return pseudo_gt_from_landmarks(rgb, landmarks, settings) | {"notes": notes, "faces": table}


def face_notes(found, settings: PseudoGTSettings) -> list[str]:
    """What the summary says about the detections: how many, their scores, which was kept, found how."""
    faces = found if isinstance(found, list) else [{}] * int(found)  # a stand-in detector may give a count
    notes = []
    if len(faces) > 1:
        scores = ", ".join(f"{f['score']:.2f}" for f in faces if "score" in f)
        notes.append(
            f"{len(faces)} faces{f' (detection scores {scores}, largest first)' if scores else ''}: "
            f"kept {'the largest' if settings.face == 0 else f'face {settings.face} by size'}"
        )
    if faces and faces[0].get("upsample", settings.upsample) != settings.upsample:
        notes.append(f"face found at detector upsampling {faces[0]['upsample']}")
    return notes


def crop_pixels(crop: np.ndarray) -> np.ndarray:
    """A cached 8-bit sRGB crop ``[R, R, 3]`` as the float32 ``[3, R, R]`` linear radiance that the models, L-hat
    and SynthFaces share (:func:`disent.images.srgb_to_linear`)."""
    from disent.images import srgb_to_linear

    return srgb_to_linear(crop.astype(np.float32).transpose(2, 0, 1) / 255.0).astype(np.float32)


def pseudo_gt_from_landmarks(rgb: np.ndarray, landmarks: np.ndarray, settings: PseudoGTSettings) -> dict:
    """Steps 3-5 for a decoded photo and its 68 landmarks (no dlib needed)."""
    model = face_model_fitter(settings)
    R = settings.resolution
    crop, lm, M = align(rgb, landmarks, model.template(R), R)
    fit = fit_landmarks(lm, R, settings, model)
    maps = maps_from_fit(fit, crop_pixels(crop), model)
    sh = maps.pop("sh_pseudo")
    scale = float(np.sqrt(abs(np.linalg.det(M[:2, :2]))))
    return {
        "image": crop,
        **{k: v.astype(np.float16) for k, v in maps.items()},
        "sh_pseudo": sh.astype(np.float32),
        "landmarks": lm.astype(np.float32),
        "landmarks_fit": fit["landmarks"].astype(np.float32),
        "params": fit["params"].astype(np.float32),
        "residual_px": np.float32(fit["residual_px"]),  # RMS landmark error, crop pixels
        "residual_photo_px": np.float32(fit["residual_px"] / scale),  # the same in photo pixels
        "align": M.astype(np.float32),
    }


@dataclass
class Record:
    """What :func:`prepare` knows about one file; ``cache`` holds the arrays when ``used``."""

    path: str
    used: bool
    reason: str = ""  # why it was skipped
    detail: str = ""
    notes: list = field(default_factory=list)  # conversions applied
    digest: str = ""  # sha256 of the file's bytes
    cache: str = ""
    residual_px: float = float("nan")
    residual_photo_px: float = float("nan")
    size: int = -1
    mtime_ns: int = -1
    face: int = 0  # which face of the photo (settings.face: its rank by size)


def default_cache_dir() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "disent" / "pseudo_gt"


@functools.lru_cache(maxsize=2)
def landmark_detector(settings: PseudoGTSettings) -> LandmarkDetector:
    """One detector per settings and process (loading the predictor takes about a second)."""
    return LandmarkDetector(settings)


def _init_worker():
    """Each worker: one thread, and it exits when the process that started it is gone (killed), so an
    interrupted pass leaves no orphaned workers behind."""
    import threading
    import time

    import torch

    torch.set_num_threads(1)
    parent = os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def read_photo(path) -> bytes:
    """The bytes of an image file; :class:`Skip` ("unreadable") for a missing file, a dangling link or a folder."""
    try:
        return Path(path).read_bytes()
    except OSError as e:
        raise Skip("unreadable", f"{type(e).__name__}: {e.strerror or e}") from None


def aligned_crop(
    path, settings: PseudoGTSettings | None = None, align_face: bool = True
) -> tuple[np.ndarray, list[str]]:
    """Steps 1-3 for one image file: ``(crop uint8 [R,R,3], notes)``, framed as in training (landmark
    alignment), or a centre square crop with ``align_face=False``.  Raises :class:`Skip` for a file that
    cannot be used (unreadable, not an image, no face...), naming the reason."""
    settings = settings or PseudoGTSettings()
    rgb, notes = decode_image(read_photo(path), settings.min_side)
    R = settings.resolution
    if align_face:
        landmarks, found = landmark_detector(settings)(rgb)
        notes += face_notes(found, settings)
        crop, _, _ = align(rgb, landmarks, face_model_fitter(settings).template(R), R)
        return crop, notes
    from PIL import Image

    h, w = rgb.shape[:2]
    s = min(h, w)
    square = rgb[(h - s) // 2 : (h - s) // 2 + s, (w - s) // 2 : (w - s) // 2 + s]
    return np.asarray(Image.fromarray(square).resize((R, R), Image.LANCZOS)), notes + ["centre crop"]


def process_file(path: str, cache_root: str, settings: PseudoGTSettings, detector=None) -> Record:
    """One file through the pipeline or from the cache; never raises for a bad image."""
    try:
        st = os.stat(path)
        data = Path(path).read_bytes()
    except OSError as e:
        return Record(path, False, "unreadable", f"{type(e).__name__}: {e.strerror or e}", face=settings.face)
    digest = hashlib.sha256(data).hexdigest()
    out = Path(cache_root) / digest[:2] / f"{digest}.npz"
    rec = Record(
        path, False, digest=digest, cache=str(out), size=st.st_size, mtime_ns=st.st_mtime_ns, face=settings.face
    )
    if out.is_file():
        return _record_from_cache(rec)
    try:
        arrays = process(data, settings, detector)
        notes = arrays.pop("notes")
        arrays["notes"] = np.array(json.dumps(notes))
    except Skip as e:
        arrays = {"skip": np.array(e.reason), "detail": np.array(e.detail)}
    except (ImportError, FileNotFoundError):
        raise  # a missing dlib or predictor is a setup error, not a bad image
    except Exception as e:  # an unexpected failure on one image must not stop the batch
        log.exception("pseudo-GT failed on %s", path)
        arrays = {"skip": np.array("error"), "detail": np.array(f"{type(e).__name__}: {e}")}
    atomic_write(out, lambda f: np.savez(f, **arrays))
    return _record_from_cache(rec, arrays)


def _record_from_cache(rec: Record, arrays=None) -> Record:
    if arrays is None:
        with np.load(rec.cache) as z:
            arrays = {k: z[k] for k in ("skip", "detail", "notes", "residual_px", "residual_photo_px") if k in z}
    if "skip" in arrays:
        rec.used, rec.reason, rec.detail = False, str(arrays["skip"]), str(arrays["detail"])
    else:
        rec.used, rec.notes = True, json.loads(str(arrays["notes"]))
        rec.residual_px = float(arrays["residual_px"])
        rec.residual_photo_px = float(arrays["residual_photo_px"])
    return rec


def summarize(records: list[Record]) -> dict:
    """Counts of used and skipped images, skip reasons and conversions applied."""
    used = [r for r in records if r.used]
    res = np.array([r.residual_px for r in used]) if used else np.zeros(0)
    return {
        "total": len(records),
        "used": len(used),
        "skipped": len(records) - len(used),
        "skip_reasons": dict(Counter(r.reason for r in records if not r.used).most_common()),
        "conversions": dict(Counter(n for r in used for n in r.notes).most_common()),
        "fit_residual_px_median": float(np.median(res)) if len(res) else float("nan"),
    }


def format_summary(s: dict) -> str:
    lines = [f"pseudo-GT: {s['used']}/{s['total']} images used, {s['skipped']} skipped"]
    lines += [f"  skipped, {k}: {v}" for k, v in s["skip_reasons"].items()]
    lines += [f"  converted, {k}: {v}" for k, v in s["conversions"].items()]
    if s["used"]:
        lines.append(
            f"  landmark fit residual (median RMS): {s['fit_residual_px_median']:.2f} px at the crop resolution"
        )
    return "\n".join(lines)


def prepare(
    paths,
    settings: PseudoGTSettings | None = None,
    cache_dir=None,
    workers: int = 0,
    progress: bool = True,
    detector=None,
    log_summary: bool = True,
) -> tuple[list[Record], dict]:
    """Pseudo ground truth for every path, cached; returns the records (in input order) and a summary.

    The manifest ``<cache>/<settings key>/manifest.jsonl`` maps (path, size, mtime) to the content
    hash, so a second pass neither reads nor hashes unchanged files; each result is written as it
    is finished (atomic rename), so an interrupted pass loses nothing it completed.
    ``workers=0`` runs in this process; ``workers>0`` uses that many processes.  ``detector``
    replaces dlib by any callable ``rgb -> (landmarks [68,2], faces or their count)`` (in this process only;
    its results are cached apart, under its ``name`` attribute or class name).
    """
    from tqdm.auto import tqdm

    settings = settings or PseudoGTSettings()
    paths = [os.path.abspath(p) for p in paths]  # abspath, not resolve: a link keeps its own name
    root = Path(cache_dir or default_cache_dir()) / settings.key()
    if detector is not None:
        workers = 0
        root = root / f"detector-{getattr(detector, 'name', type(detector).__name__)}"
    root.mkdir(parents=True, exist_ok=True)
    manifest = root / "manifest.jsonl"
    records, todo = _cached(paths, _read_manifest(manifest))
    bar = tqdm(
        total=len(paths),
        initial=len(paths) - len(todo),
        desc="pseudo-GT",
        unit="img",
        disable=not progress,
        dynamic_ncols=True,
    )
    with open(manifest, "a") as mf:

        def done(i, rec):
            records[i] = rec
            if rec.digest:  # unreadable files are not cached: they may be readable next time
                mf.write(json.dumps(dataclasses.asdict(rec)) + "\n")
                mf.flush()
            bar.update(1)

        if workers and len(todo) > 1:
            import multiprocessing as mp

            with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_init_worker) as pool:
                queue, running = iter(todo), {}
                while True:  # at most 8 tasks per worker in flight, so a huge folder needs no huge queue
                    for i in itertools.islice(queue, 8 * workers - len(running)):
                        running[pool.submit(process_file, paths[i], str(root), settings)] = i
                    if not running:
                        break
                    finished, _ = wait(running, return_when=FIRST_COMPLETED)
                    for f in finished:
                        done(running.pop(f), f.result())
        else:
            for i in todo:
                done(i, process_file(paths[i], str(root), settings, detector))
    bar.close()
    out = [records[i] for i in range(len(paths))]
    summary = summarize(out)
    for r in out:
        if not r.used:
            log.debug("skipped %s: %s%s", r.path, r.reason, f" ({r.detail})" if r.detail else "")
    if log_summary:
        log.info("%s\n  per file: %s", format_summary(summary), manifest)
    return out, summary


def _cached(paths: list[str], known: dict[str, Record]) -> tuple[dict[int, Record], list[int]]:
    """The records of the paths the manifest knows unchanged (same size and mtime, cache file present), by index,
    and the indices of the rest, to be processed."""
    records: dict[int, Record] = {}
    todo = []
    for i, p in enumerate(paths):
        rec = known.get(p)
        try:
            st = os.stat(p)
        except OSError:
            st = None
        if rec and st and (rec.size, rec.mtime_ns) == (st.st_size, st.st_mtime_ns) and Path(rec.cache).is_file():
            records[i] = rec
        else:
            todo.append(i)
    return records, todo


def _read_manifest(path: Path) -> dict[str, Record]:
    known = {}
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                rec = Record(**json.loads(line))
            except (ValueError, TypeError):
                continue  # a line cut by an interrupted write
            known[rec.path] = rec
    return known


def load_cached(rec: Record) -> dict:
    """The arrays of a used record, from its cache file."""
    with np.load(rec.cache) as z:
        return {k: z[k] for k in z.files}
