"""SynthFaces against its contract: the image model, ground truth, determinism, splits."""

import math

import pytest
import torch
import torch.nn.functional as F

from disent.data import ATTR_PRIOR, LIGHT_BANK, LIGHT_NAMES, SPLITS, SynthFaces
from disent.data.synth.face_model import GRID_U, GRID_V, face_model
from disent.data.synth.raster import (
    face_ids,
    grid_faces,
    grid_to_uv_map,
    grid_vertex_normals,
    interpolate,
    interpolate_covered,
    paste,
    pick,
    rasterize,
    rasterize_grids,
    render_face,
    sample_texture,
    to_camera,
    vertex_normals,
)
from disent.data.synth.scenes import (
    LAYERS,
    _pseudo_geometry,
    dominant_light,
    lights_to_sh,
    paint_layers,
    pseudo_mesh,
    pseudo_quads,
    sample_lights,
    shade,
    uniform,
)
from disent.render import composite, fit_sh, fit_sh_packed, image_formation, sh_basis, sh_from_directions, sh_shading

IMAGE_KEYS = (
    "image",
    "background",
    "albedo",
    "shading",
    "normal",
    "normal_uv",
    "albedo_uv",
    "normal_pseudo",
    "normal_uv_pseudo",
)


@pytest.fixture(scope="module")
def train():
    return SynthFaces("train", resolution=64, seed=0)


@pytest.fixture(scope="module")
def batch(train):
    return train.get_batch(range(12))


def test_item_keys_shapes_and_ranges(train, batch):
    item = train[3]
    H = 64
    shapes = {
        "image": (3, H, H),
        "background": (3, H, H),
        "matte": (1, H, H),
        "normal": (3, H, H),
        "albedo": (3, H, H),
        "shading": (3, H, H),
        "sh": (3, 9),
        "uv": (2, H, H),
        "normal_uv": (3, H, H),
        "albedo_uv": (3, H, H),
        "normal_pseudo": (3, H, H),
        "mask_pseudo": (1, H, H),
        "mask_face": (1, H, H),
        "uv_pseudo": (2, H, H),
        "normal_uv_pseudo": (3, H, H),
        "sh_pseudo": (3, 9),
        "pose": (3,),
    }
    for k, shape in shapes.items():
        assert item[k].shape == shape, k
        assert item[k].dtype == torch.float32, k
        assert torch.isfinite(item[k]).all(), k
    for k in ("image", "background", "albedo", "albedo_uv", "matte", "mask_pseudo", "uv", "uv_pseudo"):
        assert item[k].min() >= 0 and item[k].max() <= 1, k
    assert item["identity"].dtype == torch.int64 and item["light_id"].item() == -1
    assert set(item["attrs"]) == {f"{a}{s}" for a in ATTR_PRIOR for s in ("", "_strength")}
    for k, v in batch.items():  # __getitem__ (chunk cache) and get_batch agree
        if not isinstance(v, dict):
            assert torch.equal(v[3], item[k]), k


def test_resolution_128_item():
    item = SynthFaces("val", resolution=128).sample(0)
    assert item["image"].shape == (3, 128, 128) and item["albedo_uv"].shape == (3, 128, 128)
    assert item["matte"].sum() > 0.2 * 128 * 128


def test_normals_unit_inside_matte_zero_outside(batch):
    for n, m in ((batch["normal"], batch["matte"]), (batch["normal_pseudo"], batch["mask_pseudo"])):
        norm = n.norm(dim=1)
        inside = m[:, 0] > 0
        assert inside.any()
        assert torch.allclose(norm[inside], torch.ones_like(norm[inside]), atol=1e-5)
        assert norm[~inside].abs().max() == 0
    assert (batch["normal"][:, 2][batch["matte"][:, 0] > 0] > -0.5).all()  # visible surfaces face the camera
    for k in ("normal_uv", "normal_uv_pseudo"):
        assert torch.allclose(batch[k].norm(dim=1), torch.ones(1), atol=1e-4)


def test_image_is_the_papers_model_with_effects_off(batch):
    shading = sh_shading(batch["normal"], batch["sh"]) * batch["matte"]
    assert torch.allclose(batch["shading"], shading, atol=1e-6)
    image = composite(batch["matte"], image_formation(batch["albedo"], batch["shading"]), batch["background"])
    assert (batch["image"] - image).abs().max() < 1e-6
    # The albedo is the UV-space texture looked up at the pixel's uv.
    m = batch["matte"][:, 0] > 0
    assert batch["albedo"][:, 0][m].min() >= 0.02 - 1e-6


def test_fit_sh_with_gt_normals_and_albedo_recovers_gt_light(batch):
    d = {k: batch[k].double() for k in ("image", "normal", "matte", "albedo")}  # float64 sums: float error only
    sh, residual = fit_sh(d["image"], d["normal"], d["matte"], albedo=d["albedo"])
    sh = sh.float()
    assert residual.max() < 1e-5
    assert torch.allclose(sh, batch["sh"], atol=2e-4), (sh - batch["sh"]).abs().max()


def test_sh_pseudo_is_l_hat_of_the_pseudo_normals(batch):
    sh, _ = fit_sh(*(batch[k].double() for k in ("image", "normal_pseudo", "mask_pseudo")))
    sh = sh.float()
    assert torch.allclose(batch["sh_pseudo"], sh, atol=1e-5)
    packed = fit_sh_packed(batch["image"], batch["normal_pseudo"], batch["mask_pseudo"])
    assert torch.allclose(packed, sh, atol=1e-5)
    # A soft mask weights the pixels, as fit_sh does.
    soft = batch["mask_pseudo"] * torch.rand(batch["mask_pseudo"].shape, generator=torch.Generator().manual_seed(0))
    sh_soft = fit_sh(*(t.double() for t in (batch["image"], batch["normal_pseudo"], soft)))[0].float()
    assert not torch.allclose(sh_soft, sh, atol=1e-3)
    assert torch.allclose(fit_sh_packed(batch["image"], batch["normal_pseudo"], soft), sh_soft, atol=1e-5)
    # Over an albedo map, with the same rule: pixels where the albedo is ~0 (here a dark band) are left out.
    albedo = batch["albedo"].clone()
    albedo[..., 20:26, :] = 0
    want = fit_sh(*(t.double() for t in (batch["image"], batch["normal_pseudo"], batch["mask_pseudo"], albedo)))[0]
    assert not torch.allclose(want.float(), sh, atol=1e-2)
    packed = fit_sh_packed(batch["image"], batch["normal_pseudo"], batch["mask_pseudo"], albedo)
    assert torch.allclose(packed, want.float(), atol=1e-5), (packed - want).abs().max()


def test_pseudo_gt_error_in_the_stated_band():
    b = SynthFaces("test", seed=1).get_batch(range(32))
    both = (b["matte"] * b["mask_pseudo"])[:, 0] > 0
    cos = (b["normal"] * b["normal_pseudo"]).sum(1).clamp(-1, 1)[both]
    err = torch.rad2deg(torch.acos(cos)).mean().item()
    assert 8.0 <= err <= 25.0, err
    # The coarse fit covers the face, not the hair: its mask lies mostly inside the true matte.
    assert (b["mask_pseudo"] * b["matte"]).sum() / b["mask_pseudo"].sum() > 0.9


def test_mask_face_is_the_skin_that_mask_pseudo_estimates():
    """``mask_face``, the face region through the true mesh, is binary, lies inside the head (the true matte) and
    leaves out hair, ears and neck; M-hat (mask_pseudo, the coarse fit's face region) estimates it far better than
    it estimates the whole head."""
    from disent.eval.metrics import mask_iou

    b = SynthFaces("test", seed=1).get_batch(range(32))
    face, head = b["mask_face"], b["matte"]
    assert set(face.unique().tolist()) == {0.0, 1.0}
    assert ((face > 0.5) & (head < 0.5)).sum() == 0  # inside the head
    assert face.sum() < 0.7 * (head > 0.99).sum()  # not the hair, ears and neck
    assert mask_iou(b["mask_pseudo"], face) > 0.75 and mask_iou(b["mask_pseudo"], head) < 0.6


def test_same_seed_same_bytes_any_batching():
    a = SynthFaces("val", seed=3).get_batch([5, 6, 7])
    b = SynthFaces("val", seed=3).get_batch([7, 1, 5])
    single = SynthFaces("val", seed=3).get_batch([6])  # batch size does not change a single bit
    for k in ("image", "normal", "sh", "sh_pseudo"):
        assert torch.equal(single[k][0], a[k][1]), k
    c = SynthFaces("val", seed=4).get_batch([5])
    for k in ("image", "normal", "albedo", "sh", "sh_pseudo", "background", "normal_pseudo"):
        assert a[k][0].numpy().tobytes() == b[k][2].numpy().tobytes(), k
        assert a[k][2].numpy().tobytes() == b[k][0].numpy().tobytes(), k
    assert not torch.equal(a["image"][0], c["image"][0])
    assert not torch.equal(a["image"][0], a["image"][1])


def test_counter_based_uniforms():
    key = torch.arange(5000)
    u = uniform(key, "pose", 4, seed=0)
    assert u.min() > 0 and u.max() < 1
    assert abs(u.mean().item() - 0.5) < 0.01 and abs(u.var().item() - 1 / 12) < 0.005
    assert torch.equal(u[1234], uniform(key[1234:1235], "pose", 4, seed=0)[0])
    assert abs(torch.corrcoef(torch.stack([u[:, 0], uniform(key, "light", 1, 0)[:, 0]]))[0, 1]) < 0.05


def _layer(*names, res=64):
    L = paint_layers(res)
    return sum(L[LAYERS.index(n)] for n in names).reshape(res, res)


@pytest.mark.parametrize(
    "attr,layers", [("beard", ("beard_full", "beard_goatee")), ("eyeglasses", ("glasses_round", "glasses_square"))]
)
def test_albedo_attributes_change_only_their_region(train, attr, layers):
    off, on = train.sample(2, **{attr: 0.0}), train.sample(2, **{attr: 1.0})
    assert on["attrs"][attr] == 1 and off["attrs"][attr] == 0
    diff = (on["albedo_uv"] - off["albedo_uv"]).abs().amax(0)
    region = _layer(*layers) > 1e-6
    assert diff[region].max() > 0.1
    assert diff[~region].max() < 1e-6
    for k in ("normal", "matte", "sh", "background", "normal_pseudo"):  # albedo only: no geometry, no light
        assert torch.equal(on[k], off[k]), k


def test_smiling_changes_the_expression_only(train):
    off, on = train.sample(1, smiling=0.0), train.sample(1, smiling=1.0)
    assert torch.equal(on["albedo_uv"], off["albedo_uv"]) and torch.equal(on["sh"], off["sh"])
    assert torch.equal(on["background"], off["background"])
    d = (on["normal_uv"] - off["normal_uv"]).norm(dim=0)  # in UV space: rows of the lower face only
    rows = d.amax(1)
    eye_row = int(0.38 * 64)
    assert rows[eye_row + 8 :].max() > 0.3 and rows[:eye_row].max() < 1e-3
    # Teeth show when the mouth opens: the smiling image has teeth-coloured pixels in the mouth.
    teeth = _layer("teeth") > 0.5
    uv = (on["uv"] * 63).round().long()
    hit = teeth[uv[1], uv[0]] & (on["matte"][0] > 0)
    assert hit.sum() >= 2
    uv = (off["uv"] * 63).round().long()
    assert (teeth[uv[1], uv[0]] & (off["matte"][0] > 0)).sum() == 0


def test_senior_changes_albedo_and_shape_not_light(train):
    off, on = train.sample(4, senior=0.0), train.sample(4, senior=1.0)
    assert not torch.equal(on["normal_uv"], off["normal_uv"])
    sat = lambda a: (a.amax(0) - a.amin(0)).mean()  # noqa: E731
    assert sat(on["albedo_uv"]) < sat(off["albedo_uv"])  # desaturated
    assert torch.equal(on["sh"], off["sh"]) and torch.equal(on["background"], off["background"])


def test_sample_overrides(train):
    sh = LIGHT_BANK["flash_az-45"]
    a = train.sample(7, sh=sh)
    assert torch.equal(a["sh"], sh) and a["light_id"] == -1
    b = train.sample(7, light="flash_az-45")
    assert torch.equal(b["sh"], sh) and b["light_id"] == LIGHT_NAMES.index("flash_az-45")
    assert torch.equal(a["image"], b["image"])
    c = train.sample(7, pose=(0.0, 0.0, 0.0))
    assert torch.equal(c["pose"], torch.zeros(3))
    base = train[7]
    assert torch.equal(train.sample(7)["image"], base["image"])
    assert torch.equal(c["albedo_uv"], base["albedo_uv"])  # same face, new pose
    with pytest.raises(ValueError):
        train.sample(7, hair=1.0)
    with pytest.raises(ValueError):
        train.sample(7, beard=2.0)


def test_effects_off_by_default_and_each_changes_the_image(train):
    base = train.sample(5)
    for e in ("specular", "cast_shadow", "noise", "occluder"):
        lo, hi = train.sample(5, effects={e: 0.3}), train.sample(5, effects={e: 1.0})
        d_lo, d_hi = (lo["image"] - base["image"]).abs().mean(), (hi["image"] - base["image"]).abs().mean()
        assert 0 < d_lo < d_hi, e
        assert torch.equal(hi["normal"], base["normal"]) and torch.equal(hi["albedo"], base["albedo"])
        assert hi["image"].min() >= 0 and hi["image"].max() <= 1
    with pytest.raises(ValueError):
        SynthFaces("train", effects={"fog": 0.5})
    with pytest.raises(ValueError):
        train.sample(0, effects={"noise": 1.5})


def test_specular_follows_the_light_given_to_sample(train):
    """The highlight comes from the scene's SH light, so an overridden light moves it."""

    def highlight_x(sh):
        on = train.sample(9, sh=sh, pose=(0.0, 0.0, 0.0), effects={"specular": 1.0})
        off = train.sample(9, sh=sh, pose=(0.0, 0.0, 0.0))
        h = (on["image"] - off["image"]).sum(0).clamp_min(0)
        assert h.sum() > 0.5
        return (h * torch.arange(64.0)).sum() / h.sum()

    left, right = highlight_x(LIGHT_BANK["flash_az-60"]), highlight_x(LIGHT_BANK["flash_az+60"])
    assert right - left > 8, (left, right)  # light from image right: highlight on the right
    none = train.sample(9, sh=LIGHT_BANK["ambient"], effects={"specular": 1.0})
    assert torch.equal(none["image"], train.sample(9, sh=LIGHT_BANK["ambient"])["image"])  # no direction, no highlight


def test_dominant_light_of_one_distant_light():
    d = torch.nn.functional.normalize(torch.tensor([[0.3, 0.5, 0.8], [-0.6, -0.1, 0.4]]), dim=1)
    intensity = torch.tensor([[0.7, 0.8, 0.9], [1.0, 1.0, 0.5]])
    sh = sh_from_directions(d[:, None].double(), intensity[:, None].double(), 0.2).float()
    direction, key = dominant_light(sh)
    assert torch.allclose(direction, d, atol=1e-5) and torch.allclose(key, intensity, atol=1e-4)


def test_light_prior_and_bank_are_plausible():
    assert len(LIGHT_BANK) >= 20
    g = torch.Generator().manual_seed(0)
    n = torch.nn.functional.normalize(torch.randn(20000, 3, generator=g), dim=1)
    n = n[n[:, 2] >= 0]  # the visible hemisphere
    basis = sh_basis(n.T, 0)
    sh = torch.cat([sample_lights(torch.rand(500, 12, generator=g))["sh"], torch.stack(list(LIGHT_BANK.values()))])
    s = sh @ basis
    assert s.min() >= 0 and s.amax((1, 2)).max() <= 1.01
    # Colour: slightly tinted, not grey, not saturated.
    ratio = sh[:, 0, 0] / sh[:, 2, 0]
    assert 0.7 < ratio.min() and ratio.max() < 1.4 and ratio.std() > 0.01
    # A single light projects to max(0, n.d) up to the order-2 truncation.
    d = torch.tensor([[0.0, 0.0, 1.0]])
    one = lights_to_sh(d[None], torch.ones(1, 1, 3), torch.zeros(1, 3), torch.tensor([1.0]), floor=0.0)
    assert one[0, 0, 0] > 0


@pytest.mark.parametrize("split", list(SPLITS))
def test_split_sizes_and_balance(split):
    ds = SynthFaces(split)
    expected = {"train": 20000, "val": 1000, "test": 1000, "lightbank": len(LIGHT_NAMES) * 50 * 3}.get(split, 4000)
    assert len(ds) == expected
    idx = range(0, min(len(ds), 2000 if split in ("train", "val", "test") else 1000))  # a contiguous block
    p = ds.params(idx)
    if split.startswith("pool_"):
        attr = split[5:]
        labels = (p[attr] >= 0.5).float()
        assert labels.sum() == len(idx) / 2 and len(ds) // 2 >= 2000
    elif split == "lightbank":
        p = ds.params(range(len(ds)))
        assert torch.equal(torch.bincount(p["light_id"]), torch.full((len(LIGHT_NAMES),), 150))
        assert p["identity"].unique().numel() == 50 and p["pose"][:, 0].unique().numel() == 3
        same = ds.params(range(len(LIGHT_NAMES)))  # one identity and pose under every light
        assert torch.equal(same["bg"], same["bg"][:1].expand_as(same["bg"]))
    else:
        for attr, prior in ATTR_PRIOR.items():
            freq = (p[attr] >= 0.5).float().mean().item()
            n = len(idx) if attr == "smiling" else p["identity"].unique().numel()  # identity-level draws
            assert abs(freq - prior) < 4 * math.sqrt(prior * (1 - prior) / n), (attr, freq)
        assert (
            p["pose"][:, 0].abs().max() <= 45
            and p["pose"][:, 1].abs().max() <= 20
            and p["pose"][:, 2].abs().max() <= 10
        )
    assert SynthFaces(split, size=10).params(range(10))["identity"].shape == (10,)


def test_splits_have_disjoint_identities():
    ids = {s: set(SynthFaces(s).params(range(0, 1000, 7))["identity"].tolist()) for s in ("train", "val", "test")}
    assert not (ids["train"] & ids["val"]) and not (ids["train"] & ids["test"]) and not (ids["val"] & ids["test"])


def test_bad_input_is_refused(train):
    with pytest.raises(ValueError):
        SynthFaces("validation")
    with pytest.raises(ValueError):
        SynthFaces("train", resolution=96)
    with pytest.raises(IndexError):
        train[len(train)]
    with pytest.raises(IndexError):
        train.get_batch([-1])


def test_dataloader_renders_batches_together(train):
    loader = torch.utils.data.DataLoader(SynthFaces("val", size=12), batch_size=6, shuffle=False)
    first = next(iter(loader))
    ref = SynthFaces("val", size=12).get_batch(range(6))
    assert torch.equal(first["image"], ref["image"]) and torch.equal(first["attrs"]["beard"], ref["attrs"]["beard"])


# ----------------------------------------------------------------------------- face model and rasterizer
def test_face_model_sizes_and_landmarks():
    fm = face_model()
    assert fm.mean.shape == (GRID_U * GRID_V, 3) and fm.identity.shape[0] >= 20 and fm.expression.shape[0] == 2
    lm = fm.landmarks
    assert lm.shape == (68,) and lm.unique().numel() == 68
    x = fm.mean[lm, 0]
    for a, b in ((0, 16), (36, 45), (39, 42), (48, 54), (17, 26), (31, 35)):  # mirror pairs
        assert x[a] < 0 < x[b] and abs(x[a] + x[b]) < 0.06, (a, b)
    assert (x[:17].diff() > 0).all()  # jaw runs from image left to right
    y = fm.mean[lm, 1]
    assert y[19] > y[37] > y[30] > y[51] > y[57] > y[8]  # brow above eye above nose tip above lips above chin
    ident = fm.identity.flatten(1).norm(dim=1)
    assert (ident.diff() <= 1e-6).all()  # ordered by variance


def _square(z=0.0, offset=0.0, size=1.0):
    v = torch.tensor([[-1, 1], [1, 1], [-1, -1], [1, -1]], dtype=torch.float32) * size / 2 + offset
    return torch.cat([v, torch.full((4, 1), z)], 1), torch.tensor([[0, 2, 1], [1, 2, 3]])


def test_rasterizer_coverage_depth_and_barycentrics():
    H = 32
    va, fa = _square(z=0.0, size=1.0)
    vb, fb = _square(z=0.5, offset=0.5, size=1.0)  # nearer, overlapping the first's top-right quarter
    verts = torch.cat([va, vb])[None]
    faces = torch.cat([fa, fb + 4])
    r = rasterize(verts, faces, H)
    mask = r["face_id"][0] >= 0
    # The union of two half-image squares offset by a quarter image: 2 * 16^2 - 8^2 pixel centres.
    assert mask.sum() == 2 * 16 * 16 - 8 * 8
    near = r["face_id"][0] >= 2
    assert near.sum() == 16 * 16  # the nearer square is entirely visible
    # Interpolating the vertices' own x, y gives back each pixel centre (linear, orthographic).
    pix = interpolate(verts[0], r)[0]
    centres = (torch.arange(H) * 2 + 1) / H - 1
    assert torch.allclose(pix[0][mask], centres.expand(H, H)[mask], atol=1e-5)
    assert torch.allclose(pix[1][mask], centres.flip(0)[:, None].expand(H, H)[mask], atol=1e-5)
    assert torch.allclose(pix[2][near], torch.full_like(pix[2][near], 0.5))
    # Back-facing triangles are culled.
    flipped = rasterize(verts, faces[:, [0, 2, 1]], H)
    assert (flipped["face_id"] < 0).all()


def test_paste_pick_and_texture_lookup_at_covered_pixels():
    """paste / pick are inverse on the covered pixels; paste onto a background is Eq. 6 with a binary
    matte, exactly; sample_texture is grid_sample(align_corners=True) at the covered pixels."""
    fm = face_model()
    p = SynthFaces("val", seed=6).params(range(3))
    cam = to_camera(fm.shape(p["alpha"], p["expression"], p["senior"]), p["pose"], p["scale"], p["shift"])
    r = rasterize_grids([(cam, (GRID_V, GRID_U))], 32)[0]
    g = torch.Generator().manual_seed(0)
    values = torch.rand(3, r["batch"].numel(), generator=g)
    background = torch.rand(3, 3, 32, 32, generator=g)
    matte = paste(torch.ones(1, values.shape[1]), r)
    assert torch.equal(matte[:, 0] > 0, face_ids(r) >= 0)
    assert torch.equal(pick(paste(values, r), r), values)
    assert torch.equal(paste(values, r, background), composite(matte, paste(values, r), background))
    texture = torch.rand(3, 3, 16, 16, generator=g)
    uv = interpolate_covered(fm.uv, r)
    uv[:, :4] = torch.tensor([[0.0, 1.0, 1.0, 0.0], [0.0, 0.0, 1.0, 1.0]])  # the corners of UV space
    ref = pick(F.grid_sample(texture, (2 * paste(uv, r) - 1).permute(0, 2, 3, 1), align_corners=True), r)
    assert torch.allclose(sample_texture(texture, uv, r["batch"]), ref, atol=1e-6)


def test_render_face_layers():
    fm = face_model()
    cam = fm.mean[None] * 0.8
    g = render_face(cam, fm.faces, fm.uv, 64, (GRID_V, GRID_U))
    m = g["mask"][0, 0] > 0
    assert 0.3 < m.float().mean() < 0.8
    assert (g["normal"][0, 2][m] > -0.3).all()  # a frontal face: normals towards the camera
    assert g["uv"][0][:, m].min() >= 0 and g["uv"][0][:, m].max() <= 1
    # Left half of the image sees the subject's right side (u < 0.5), normals pointing left.
    assert g["uv"][0, 0, 32, 16] < 0.5 < g["uv"][0, 0, 32, 48]
    assert g["normal"][0, 0, 32, 16] < 0 < g["normal"][0, 0, 32, 48]
    assert math.isclose(g["depth"][0, 0][m].max().item(), cam[0, :, 2].max().item(), rel_tol=0.05)


def test_grid_rasterizer_matches_the_triangle_rasterizer():
    """rasterize_grids (quads, several meshes at once) and rasterize (triangles) see the same pixels."""
    fm = face_model()
    p = SynthFaces("val", seed=2).params(range(6))
    cam = to_camera(fm.shape(p["alpha"], p["expression"], p["senior"]), p["pose"], p["scale"], p["shift"])
    fit = _pseudo_geometry(p)
    idx, faces, _, grid = pseudo_mesh()
    assert torch.equal(grid_faces(GRID_V, GRID_U), fm.faces)
    for res in (48, 64, 128):  # 48: pixel counts that are no power of two
        grids = rasterize_grids([(cam, (GRID_V, GRID_U)), (fit["cam"], grid)], res)
        for g, (verts, f) in zip(grids, ((cam, fm.faces), (fit["cam"], faces))):
            t = rasterize(verts.contiguous(), f, res)
            g_id = face_ids(g)
            assert ((g_id >= 0) != (t["face_id"] >= 0)).sum() <= 2  # a centre exactly on an outline edge
            same = g_id == t["face_id"]
            assert same.float().mean() > 0.9995
            a, b = interpolate(verts, g), interpolate(verts, t)  # x, y: the pixel centres; z: depth
            centres = (torch.arange(res) * 2 + 1) / res - 1
            covered = g_id >= 0
            assert (a[:, 0] - centres)[covered].abs().max() < 1e-3 and (a[:, 1] - centres.flip(0)[:, None])[
                covered
            ].abs().max() < 1e-3
            assert (a - b).abs().amax(1)[same].max() < 1e-3  # slivers of the closed mouth: rounding of tiny areas


def test_grid_rasterizer_splits_a_batch_too_large_for_float32_pixel_ids(monkeypatch):
    """Over the pixel-id limit the batch is rasterized in halves: the same lists, offsets and all."""
    import disent.data.synth.raster as raster

    p = SynthFaces("val", seed=2).params(range(5))
    fm = face_model()
    cam = to_camera(fm.shape(p["alpha"], p["expression"], p["senior"]), p["pose"], p["scale"], p["shift"])
    fit = _pseudo_geometry(p)
    meshes = [(cam, (GRID_V, GRID_U)), (fit["cam"], fit["grid"], pseudo_quads())]
    whole = rasterize_grids(meshes, 32)
    monkeypatch.setattr(raster, "_MAX_PIXELS", 3 * 32 * 32)  # 10 images: split down to 1 or 2 per call
    split = rasterize_grids(meshes, 32)
    for a, b, (verts, *_) in zip(whole, split, meshes):
        assert a["size"] == b["size"] and a["grid"] == b["grid"]
        assert torch.equal(face_ids(a), face_ids(b)) and (face_ids(a) >= 0).any()
        assert torch.allclose(interpolate(verts, a), interpolate(verts, b))


def test_pseudo_fit_draws_only_its_face_quads():
    """Only quads touching the face region can enter mask_pseudo; drawing only those changes no pixel."""
    p = SynthFaces("train", seed=5).params(range(32))
    fit = _pseudo_geometry(p)
    idx, faces, _, grid = pseudo_mesh()
    region = face_model().face_region[idx, None]
    masks = []
    for mesh in ((fit["cam"], grid), (fit["cam"], grid, pseudo_quads())):
        r = rasterize_grids([mesh], 64)[0]
        pix = interpolate([fit["vn"], region], r)
        masks.append(((face_ids(r) >= 0) & (pix[:, 3] > 0.5), pix[:, :3]))
    assert 0.3 < pseudo_quads().float().mean() < 0.8
    assert torch.equal(masks[0][0], masks[1][0]) and masks[0][0].any()
    m = masks[0][0][:, None].expand(-1, 3, -1, -1)
    assert torch.equal(masks[0][1][m], masks[1][1][m])


def test_shade_is_eq4_times_the_matte():
    g = torch.Generator().manual_seed(0)
    n = torch.nn.functional.normalize(torch.randn(4, 3, 8, 8, generator=g, dtype=torch.float64), dim=1)
    matte = (torch.rand(4, 1, 8, 8, generator=g) > 0.3).double()
    sh = torch.randn(4, 3, 9, generator=g, dtype=torch.float64)
    assert torch.allclose(shade(n * matte, sh, matte), sh_shading(n, sh) * matte, atol=1e-12)


def test_grid_to_uv_map_reproduces_bilinear_functions():
    # Piecewise-linear interpolation between any knots is exact for f = a + b v + c u + d u v.
    g = torch.Generator().manual_seed(0)
    kv = torch.cat([torch.zeros(1), torch.rand(7, generator=g).sort().values * 0.9 + 0.05, torch.ones(1)]).double()
    ku = torch.cat([torch.zeros(1), torch.rand(4, generator=g).sort().values * 0.9 + 0.05, torch.ones(1)]).double()
    a, b, c, d = torch.randn(4, 2, 5, generator=g, dtype=torch.float64)
    f = lambda v, u: (
        a[:, :, None, None] + b[:, :, None, None] * v + c[:, :, None, None] * u + d[:, :, None, None] * u * v
    )
    vals = f(kv[:, None], ku[None]).reshape(2, 5, -1).transpose(1, 2)  # [B, V, C]
    out = grid_to_uv_map(vals, 16, (len(kv), len(ku)), knots=(kv, ku))
    t = torch.linspace(0, 1, 16, dtype=torch.float64)
    assert torch.allclose(out, f(t[:, None], t[None]), atol=1e-12)
    uniform_knots = torch.linspace(0, 1, 9, dtype=torch.float64), torch.linspace(0, 1, 6, dtype=torch.float64)
    vals = f(uniform_knots[0][:, None], uniform_knots[1][None]).reshape(2, 5, -1).transpose(1, 2)
    assert torch.allclose(grid_to_uv_map(vals, 16, (9, 6)), f(t[:, None], t[None]), atol=1e-12)


def test_grid_vertex_normals_of_a_plane():
    # A tilted plane: every vertex normal is the plane's, as the triangle mesh's area-weighted normals give it.
    gv, gu = 6, 5
    v, u = torch.meshgrid(
        torch.linspace(0, 1, gv, dtype=torch.float64), torch.linspace(0, 1, gu, dtype=torch.float64), indexing="ij"
    )
    x, y = u - 0.5, 0.5 - v  # rows run down the image, columns right
    verts = torch.stack([x, y, 0.3 * x - 0.2 * y], -1).reshape(1, -1, 3)
    n = grid_vertex_normals(verts, (gv, gu))
    assert torch.allclose(n, vertex_normals(verts, grid_faces(gv, gu)), atol=1e-12)
    plane = torch.tensor([-0.3, 0.2, 1.0], dtype=torch.float64)
    assert torch.allclose(n[0], (plane / plane.norm()).expand(gv * gu, 3), atol=1e-12)


def test_contact_sheet_refuses_a_non_png_out_before_rendering(tmp_path, capsys, monkeypatch):
    """``--out FOLDER`` (or another image type) stops at once with a clear error, before minutes of rendering."""
    from disent.data.synth import sheet

    monkeypatch.setattr(sheet, "contact_sheet", lambda *a: pytest.fail("rendered before checking --out"))
    for out in (tmp_path, tmp_path / "sheet.jpg"):
        with pytest.raises(SystemExit):
            sheet.main(["--out", str(out)])
        assert "give a .png file to write" in capsys.readouterr().err


def test_the_device_path_renders_what_the_cpu_path_renders():
    """``SynthFaces(device=...)`` (``data.device``) draws the scene parameters on the CPU and renders where it is told:
    with the device set to the CPU, the device path's batch is the CPU path's, bit for bit, and the training data
    built from a config with ``data.device=cpu`` is the default's."""
    from omegaconf import OmegaConf

    from disent.config import NOT_DEFINING
    from disent.data import make_dataset

    plain = SynthFaces("train", resolution=64, seed=3, size=40)
    on_cpu = SynthFaces("train", resolution=64, seed=3, size=40, device=torch.device("cpu"))
    a, b = plain.get_batch(range(5, 17)), on_cpu.get_batch(range(5, 17))
    assert set(a) == set(b)
    for k in a:
        if torch.is_tensor(a[k]):
            assert torch.equal(a[k], b[k]), k
    cfg = OmegaConf.create({"name": "synth", "resolution": 64, "seed": 3, "effects": None, "device": "cpu"})
    made = make_dataset(cfg, "train", 40)
    assert made.device == torch.device("cpu") and torch.equal(made.get_batch([7])["image"], a["image"][2:3])
    assert "data.device" in NOT_DEFINING  # a run resumed on another device trains on as before


def test_cached_scene_tables_are_built_on_the_cpu_and_copied_once_to_the_rendering_device():
    """The builders of SynthFaces' fixed tables (the face model, the painted masks, the coarse fit's mesh) run on the
    CPU, where their seeded generators live, whatever device the batch renders on; under another default device the
    result is a copy there, made once, that shares no cache with the CPU's."""
    from disent.data.synth.face_model import face_model
    from disent.data.synth.scenes import paint_layers, pseudo_mesh

    cpu_layers, cpu_model = paint_layers(64), face_model()
    with torch.device("meta"):  # a device with no data: what lands there is only placed, not computed
        layers, model, mesh = paint_layers(64), face_model(), pseudo_mesh()
        assert paint_layers(64) is layers and face_model() is model  # copied once
    assert layers.device.type == model.mean.device.type == model.uv.device.type == mesh[0].device.type == "meta"
    assert layers.shape == cpu_layers.shape and mesh[3] == pseudo_mesh()[3]  # the grid shape, a plain tuple
    assert model._cache is not cpu_model._cache
    assert paint_layers(64) is cpu_layers and paint_layers(64).device.type == "cpu"  # the CPU's own, untouched


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_synthfaces_rendered_on_cuda_match_the_cpu():
    """The same scene parameters give the same images on the GPU: float32 rounding, and at triangle edges a rare pixel
    whose centre lies on an edge within rounding may fall to the neighbouring triangle."""
    cpu = SynthFaces("train", resolution=64, seed=0, size=64).get_batch(range(64))
    gpu = SynthFaces("train", resolution=64, seed=0, size=64, device="cuda").get_batch(range(64))
    assert gpu["image"].is_cuda
    for k in ("image", "normal", "albedo", "shading", "matte", "normal_pseudo", "mask_pseudo", "sh_pseudo"):
        close = torch.isclose(gpu[k].cpu(), cpu[k], atol=1e-4, rtol=1e-4)
        assert close.float().mean() > 0.999, (k, close.float().mean())
    torch.testing.assert_close(gpu["sh"].cpu(), cpu["sh"])
