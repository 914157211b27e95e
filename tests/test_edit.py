"""Editing: the DMT witness and its minimiser, barycenter traversal, and lighting transfer
against ground truth built from the rendering primitives."""

import math

import numpy as np
import pytest
import torch
from scipy.optimize import minimize_scalar

from disent.edit.relight import (
    directional_light,
    ratio_relight,
    relight,
    transfer_lighting,
    with_light,
)
from disent.edit.traversal import (
    AttributePool,
    barycenter,
    choose_bandwidth,
    dmt,
    encode_pool,
    rbf_kernel,
    traverse,
    witness,
)
from disent.render import composite, detailed_albedo, sh_from_directions, sh_shading


def gaussian_sets(D=5, n=40, shift=3.0, seed=0):
    g = torch.Generator().manual_seed(seed)
    neg = torch.randn(n, D, generator=g, dtype=torch.float64)
    pos = torch.randn(n, D, generator=g, dtype=torch.float64)
    pos[:, 0] += shift
    return neg, pos


def witness_grad_closed_form(z, S, T, sigma):
    """d/dz of mean_s k(z,s) - mean_t k(z,t), k = exp(-|z-x|^2 / 2 sigma^2)."""

    def part(X):
        k = rbf_kernel(z, X, sigma)  # [B,N]
        return -(k[..., None] * (z[:, None] - X[None])).mean(1) / sigma**2

    return part(S) - part(T)


# ----------------------------------------------------------------------------- kernel and witness
def test_witness_gradient_closed_form_and_finite_differences():
    neg, pos = gaussian_sets()
    sigma = choose_bandwidth(torch.cat([neg, pos]))
    z = torch.randn(4, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(1)).requires_grad_()
    (g_auto,) = torch.autograd.grad(witness(z, neg, pos, sigma).sum(), z)
    torch.testing.assert_close(g_auto, witness_grad_closed_form(z.detach(), neg, pos, sigma), rtol=1e-10, atol=1e-12)
    h = 1e-6
    for i in range(5):
        e = torch.zeros(1, 5, dtype=torch.float64)
        e[0, i] = h
        fd = (witness(z.detach() + e, neg, pos, sigma) - witness(z.detach() - e, neg, pos, sigma)) / (2 * h)
        torch.testing.assert_close(fd, g_auto[:, i], rtol=1e-6, atol=1e-9)


def test_bandwidth_gives_mean_kernel_half_and_scales_with_codes():
    neg, pos = gaussian_sets(D=16, n=60)
    X = torch.cat([neg, pos])
    sigma = choose_bandwidth(X)
    K = rbf_kernel(X, X, sigma)
    off = K[~torch.eye(len(X), dtype=torch.bool)]
    assert abs(off.mean().item() - 0.5) < 1e-6
    assert choose_bandwidth(7.0 * X) == pytest.approx(7.0 * sigma, rel=1e-6)
    K = rbf_kernel(X, X, choose_bandwidth(X, 0.2))
    assert abs(K[~torch.eye(len(X), dtype=torch.bool)].mean().item() - 0.2) < 1e-6


def test_bandwidth_rejects_bad_input():
    with pytest.raises(ValueError):
        choose_bandwidth(torch.zeros(1, 3))
    with pytest.raises(ValueError):
        choose_bandwidth(torch.zeros(5, 3))
    with pytest.raises(ValueError):
        choose_bandwidth(torch.randn(5, 3), mean_kernel=1.5)


# ----------------------------------------------------------------------------- DMT
def test_dmt_infinite_lambda_keeps_z0_and_large_lambda_barely_moves():
    neg, pos = gaussian_sets()
    z0 = neg[:3]
    torch.testing.assert_close(dmt(z0, neg, pos, math.inf), z0, rtol=0, atol=0)
    sigma = choose_bandwidth(torch.cat([neg, pos]))
    step = (dmt(z0, neg, pos, 1e4, sigma) - z0).norm(dim=1)
    # first order: z - z0 = -sigma^2 grad w(z0) / lam
    expect = (sigma**2 * witness_grad_closed_form(z0, neg, pos, sigma) / 1e4).norm(dim=1)
    torch.testing.assert_close(step, expect, rtol=1e-3, atol=0)


def test_dmt_solution_is_stationary_and_matches_1d_reference():
    neg, pos = gaussian_sets()
    sigma = choose_bandwidth(torch.cat([neg, pos]))
    z0 = neg[:4]
    lam = 0.05
    z = dmt(z0, neg, pos, lam, sigma)
    grad = witness_grad_closed_form(z, neg, pos, sigma) + lam * (z - z0) / sigma**2
    assert grad.abs().max() < 1e-7
    # one source point, one target point, on a line: compare with a scalar minimiser
    s, t, sig, lam = torch.tensor([[0.0]], dtype=torch.float64), torch.tensor([[2.0]], dtype=torch.float64), 1.0, 0.3
    z1 = dmt(s, s, t, lam, sig).item()
    f = lambda x: math.exp(-(x**2) / 2) - math.exp(-((x - 2) ** 2) / 2) + lam * x**2 / 2
    ref = minimize_scalar(f, bounds=(0, 4), method="bounded", options={"xatol": 1e-10}).x
    assert z1 == pytest.approx(ref, abs=1e-6)


def test_smaller_lambda_moves_further_towards_target():
    neg, pos = gaussian_sets(D=8, n=80)
    sigma = choose_bandwidth(torch.cat([neg, pos]))
    z0 = neg[:10]
    lams = [1.0, 0.3, 0.1, 0.03]
    zs = [dmt(z0, neg, pos, lam, sigma) for lam in lams]
    dist = [(z - z0).norm(dim=1) for z in zs]
    wit = [witness(z, neg, pos, sigma) for z in zs]
    axis = [z[:, 0] for z in zs]  # the attribute direction
    for a, b in zip(range(len(lams) - 1), range(1, len(lams))):
        assert (dist[b] > dist[a]).all()
        assert (wit[b] < wit[a]).all()
        assert axis[b].mean() > axis[a].mean()  # per point a local minimum may slide sideways
    assert (wit[0] < witness(z0, neg, pos, sigma)).all()
    # removing the attribute: swap the roles and the move goes the other way
    back = dmt(pos[:10], pos, neg, 0.1, sigma)
    assert (back[:, 0] < pos[:10, 0]).all()


def test_dmt_lambda_is_scale_free():
    neg, pos = gaussian_sets()
    z0 = neg[:3]
    z = dmt(z0, neg, pos, 0.05)
    torch.testing.assert_close(dmt(10 * z0, 10 * neg, 10 * pos, 0.05), 10 * z, rtol=1e-5, atol=1e-6)


def test_dmt_rejects_bad_input():
    neg, pos = gaussian_sets()
    with pytest.raises(ValueError):
        dmt(neg[:2], neg, pos, 0.0)
    with pytest.raises(ValueError):
        dmt(neg[:2, :3], neg, pos, 0.1)


# ----------------------------------------------------------------------------- barycenter, traverse
def test_barycenter_closed_form():
    neg, pos = gaussian_sets()
    z0 = neg[:3]
    torch.testing.assert_close(barycenter(z0, pos, neg, 0.0), z0)
    torch.testing.assert_close(barycenter(neg.mean(0, keepdim=True), pos, neg, 1.0), pos.mean(0, keepdim=True))
    torch.testing.assert_close(barycenter(z0, pos, neg, 0.5) - z0, 0.5 * (pos.mean(0) - neg.mean(0)).expand(3, -1))


class FakeImplicit:
    """``encode`` maps an image to fixed linear projections named like the implicit model's codes."""

    def __init__(self):
        g = torch.Generator().manual_seed(0)
        self.W = {
            n: torch.randn(3 * 4 * 4, d, generator=g)
            for n, d in (("UV", 6), ("Ni", 5), ("Ai", 4), ("L", 27), ("bg", 3), ("m", 2))
        }

    def encode(self, image):
        x = image.flatten(1)
        return {n: x @ W for n, W in self.W.items()}


def test_encode_pool_and_traverse_move_only_the_chosen_manifolds():
    g = torch.Generator().manual_seed(0)
    images = torch.rand(30, 3, 4, 4, generator=g)
    labels = (torch.arange(30) % 2).float()
    images[labels > 0, 0] += 1.0  # the attribute: a brighter red channel
    model = FakeImplicit()
    pool = encode_pool(model, images, labels, "smiling", batch_size=7)
    assert set(pool.positives) == {"UV", "Ni", "Ai"} and pool.positives["UV"].shape == (15, 6)
    torch.testing.assert_close(pool.positives["Ai"], model.encode(images[labels > 0])["Ai"])
    codes = model.encode(images[:2][labels[:2] == 0])
    for method, strength in (("dmt", 0.05), ("barycenter", 1.0)):
        edited = traverse(codes, pool, method=method, strength=strength)  # default: UV and Ni
        for n in ("Ai", "L", "bg", "m"):
            assert torch.equal(edited[n], codes[n])
        for n in ("UV", "Ni"):
            assert edited[n].shape == codes[n].shape and not torch.allclose(edited[n], codes[n])
            before = (codes[n] - pool.positives[n].mean(0)).norm(dim=1)
            assert ((edited[n] - pool.positives[n].mean(0)).norm(dim=1) < before).all()
    only_ai = traverse(codes, pool, manifolds=["Ai"], strength=0.05)
    assert torch.equal(only_ai["UV"], codes["UV"]) and not torch.equal(only_ai["Ai"], codes["Ai"])
    with pytest.raises(ValueError):
        traverse(codes, pool, manifolds=["L"])
    with pytest.raises(ValueError):
        traverse(codes, pool, method="walk")
    with pytest.raises(ValueError):
        encode_pool(model, images, torch.ones(30), "smiling")


def test_attribute_pool_sets_one_bandwidth_per_manifold():
    neg, pos = gaussian_sets()
    pool = AttributePool("beard", {"Ai": pos, "Ni": 3 * pos}, {"Ai": neg, "Ni": 3 * neg})
    assert pool.sigma["Ni"] == pytest.approx(3 * pool.sigma["Ai"], rel=1e-6)


# ----------------------------------------------------------------------------- relighting
def ground_truth_scene(B=2, H=16, W=16, seed=0):
    """A sphere-cap face with random albedo in front of a random background, binary matte."""
    g = torch.Generator().manual_seed(seed)
    ys, xs = torch.meshgrid(torch.linspace(1, -1, H), torch.linspace(-1, 1, W), indexing="ij")
    r2 = xs**2 + ys**2
    matte = (r2 < 0.8).float()[None, None].expand(B, 1, H, W)
    normal = torch.stack([xs, ys, (1 - r2).clamp_min(0).sqrt()])[None].expand(B, 3, H, W) * matte
    albedo = 0.2 + 0.7 * torch.rand(B, 3, H, W, generator=g)
    background = torch.rand(B, 3, H, W, generator=g)
    return normal.double(), matte.double(), albedo.double(), background.double()


def render(normal, matte, albedo, background, sh):
    return composite(matte, albedo * sh_shading(normal, sh), background)


def two_lights(ambient):
    d = torch.tensor([[[0.6, 0.3, 0.74]], [[-0.5, -0.2, 0.84]]], dtype=torch.float64)
    sh_t = sh_from_directions(d, torch.full((2, 1, 3), 0.8, dtype=torch.float64), ambient)
    sh_s = sh_from_directions(
        d.flip(0) * torch.tensor([1.0, -1, 1], dtype=torch.float64),
        torch.tensor([[[0.9, 0.7, 0.5]], [[0.4, 0.6, 0.9]]], dtype=torch.float64),
        ambient,
    )
    return sh_t, sh_s


@pytest.mark.parametrize("ambient", [0.3, 0.0])
def test_transfer_with_true_intrinsics_reproduces_the_relit_render(ambient):
    normal, matte, albedo, bg = ground_truth_scene()
    sh_t, sh_s = two_lights(ambient)
    target = render(normal, matte, albedo, bg, sh_t)
    truth = render(normal, matte, albedo, bg, sh_s)
    S_t = sh_shading(normal, sh_t)
    if ambient == 0.0:  # real shadows: the guard must engage, and the true albedo fills them exactly
        assert ((S_t < 0.05) & (matte > 0)).any()
    out = transfer_lighting(target, normal, S_t, matte, sh_s, albedo)
    torch.testing.assert_close(out, truth, rtol=0, atol=1e-12)
    # the naive ratio relights the background too: not the truth
    naive = ratio_relight(target, normal, sh_t, sh_s)
    assert (naive - truth).abs()[(matte == 0).expand_as(truth)].max() > 0.05


def test_transfer_is_the_ratio_image_under_a_full_matte_and_blends_the_input_in_elsewhere():
    """Eq. 2's detailed albedo shaded anew is I S' / S: under a full matte transfer equals the ratio image exactly,
    and where the matte is m < 1 it is m times the ratio image plus (1 - m) times the unrelit input (Eq. 6)."""
    normal, matte, albedo, bg = ground_truth_scene()
    sh_t, sh_s = two_lights(0.3)
    target = render(normal, matte, albedo, bg, sh_t)
    S_t = sh_shading(normal, sh_t)
    soft = matte.clone()
    soft[..., :8, :] *= 0.9  # the matte's upper half at 0.9
    out = transfer_lighting(target, normal, S_t, soft, sh_s, albedo)
    ratio = ratio_relight(target, normal, sh_t, sh_s)
    lit = ((S_t >= 0.05) & (matte > 0)).expand_as(out)
    full, partial = lit & (soft == 1).expand_as(out), lit & (soft < 1).expand_as(out)
    assert full.any() and partial.any()
    torch.testing.assert_close(out[full], ratio[full], rtol=0, atol=1e-12)
    blend = 0.9 * ratio + 0.1 * target
    torch.testing.assert_close(out[partial], blend[partial], rtol=0, atol=1e-12)
    assert (out[partial] - ratio[partial]).abs().max() > 1e-3


def test_transfer_without_fallback_is_exact_where_lit():
    normal, matte, albedo, bg = ground_truth_scene()
    sh_t, sh_s = two_lights(0.0)
    target = render(normal, matte, albedo, bg, sh_t)
    S_t = sh_shading(normal, sh_t)
    out = transfer_lighting(target, normal, S_t, matte, sh_s)
    truth = render(normal, matte, albedo, bg, sh_s)
    lit = (S_t >= 0.05) & (matte > 0)
    torch.testing.assert_close(out[lit], truth[lit], rtol=0, atol=1e-12)
    assert torch.isfinite(out).all()


def test_small_shading_guard_never_gives_nan_or_inf():
    g = torch.Generator().manual_seed(0)
    image = torch.rand(2, 3, 8, 8, generator=g)
    image[0, :, :2] = 0.0
    for shading in (
        torch.zeros(2, 1, 8, 8),
        -torch.rand(2, 3, 8, 8, generator=g),
        torch.full((2, 3, 8, 8), 1e-30),
        torch.rand(2, 3, 8, 8, generator=g) * 0.1 - 0.05,
    ):
        A = detailed_albedo(image, shading)
        assert torch.isfinite(A).all()
        assert A.abs().max() <= image.max() / 0.05 + 1e-6
    normal = torch.zeros(2, 3, 8, 8)  # background normals: shading is a constant, possibly <= 0
    sh = torch.zeros(2, 3, 9)
    assert torch.isfinite(ratio_relight(image, normal, sh, torch.randn(2, 3, 9, generator=g))).all()
    with pytest.raises(ValueError):
        detailed_albedo(image * float("nan"), torch.ones(2, 3, 8, 8))


def test_directional_light_and_with_light():
    sh = directional_light([0, 0, 1], intensity=1.0)
    n = torch.tensor([0.0, 0.0, 1.0]).reshape(1, 3, 1, 1)
    assert sh.shape == (1, 3, 9)
    assert sh_shading(n, sh).flatten().tolist() == pytest.approx([1.0] * 3, abs=0.1)  # ~ max(0, n.d) at the peak
    assert (sh_shading(-n, sh) < 0.1).all()
    with pytest.raises(ValueError):
        directional_light([0, 0, 0])
    codes = {"L": torch.zeros(4, 27), "Ne": torch.ones(4, 5)}
    new = with_light(codes, sh)
    assert new["L"].shape == (4, 27) and torch.equal(new["L"][3].reshape(3, 9), sh[0])
    assert new["Ne"] is codes["Ne"] and torch.equal(codes["L"], torch.zeros(4, 27))
    with pytest.raises(ValueError):
        with_light({"z": torch.zeros(4, 8)}, sh)
    with pytest.raises(ValueError):
        with_light(codes, torch.zeros(3, 3, 9))


class TrueIntrinsicsModel:
    """A 'model' that knows the scene's true intrinsics (stands in for a perfect network)."""

    def __init__(self, normal, matte, albedo, bg, sh):
        self.n, self.m, self.a, self.bg, self.sh = normal, matte, albedo, bg, sh

    def decode(self, codes):
        sh = codes["L"].reshape(-1, 3, 9)
        shading = sh_shading(self.n, sh)
        return {
            "recon": composite(self.m, self.a * shading, self.bg),
            "normal": self.n,
            "albedo": self.a,
            "shading": shading,
            "matte": self.m,
            "sh": sh,
            "codes": codes,
        }

    def __call__(self, image):
        return self.decode({"L": self.sh.reshape(-1, 27), "Ne": torch.zeros(len(image), 1)})


def test_relight_with_a_perfect_model_matches_truth_for_transfer_and_decode():
    normal, matte, albedo, bg = ground_truth_scene()
    sh_t, sh_s = two_lights(0.2)
    model = TrueIntrinsicsModel(normal, matte, albedo, bg, sh_t)
    target = render(normal, matte, albedo, bg, sh_t)
    truth = render(normal, matte, albedo, bg, sh_s)
    for method in ("transfer", "decode"):
        torch.testing.assert_close(relight(model, target, sh_s, method), truth, rtol=0, atol=1e-12)
    assert (relight(model, target, sh_s, "ratio") - truth).abs().max() > 0.05
    with pytest.raises(ValueError):
        relight(model, target, sh_s, "magic")


# ----------------------------------------------------------------------------- measuring net
def toy_measure_set(N=256, R=16, seed=0):
    """Attribute i = a bright patch in quadrant i; light = overall brightness; pose = patch tint."""
    g = torch.Generator().manual_seed(seed)
    attrs = (torch.rand(N, 4, generator=g) > 0.5).float()
    images = 0.1 * torch.rand(N, 3, R, R, generator=g)
    h = R // 2
    for i, (y, x) in enumerate([(0, 0), (0, h), (h, 0), (h, h)]):
        images[:, :, y : y + h, x : x + h] += 0.6 * attrs[:, i, None, None, None]
    level = torch.rand(N, generator=g)
    images = images + 0.3 * level[:, None, None, None]
    sh = torch.zeros(N, 3, 9)
    sh[:, :, 0] = level[:, None] * 2.0
    pose = torch.stack([30 * level, torch.zeros(N), torch.zeros(N)], 1)
    tint = torch.rand(N, generator=g)
    images[:, 2] += 0.3 * tint[:, None, None]
    return images, attrs, sh, pose, tint[:, None]


def test_measure_net_learns_a_toy_set_and_round_trips(tmp_path):
    from disent.edit.classifier import fit_measure_net, load_measure_net, measure_accuracy, save_measure_net

    images, attrs, sh, pose, identity = toy_measure_set()
    net = fit_measure_net(images, attrs, sh, pose, identity, steps=400, batch_size=32, width=8)
    test = toy_measure_set(seed=1)
    acc = measure_accuracy(net, *test)
    assert min(acc[f"acc_{a}"] for a in ("smiling", "beard", "eyeglasses", "senior")) > 0.9
    assert acc["sh_rmse"] < 0.5 * acc["sh_std"] and acc["pose_mae_deg"] < 0.5 * acc["pose_std_deg"]
    assert acc["identity_rmse_std"] < 0.5
    save_measure_net(net, tmp_path / "m.pt")
    again = load_measure_net(tmp_path / "m.pt")
    torch.testing.assert_close(again(test[0][:4])["sh"], net(test[0][:4])["sh"])


# ----------------------------------------------------------------------------- measured tables, end to end
class FakeSynth(torch.utils.data.Dataset):
    """SynthFaces' interface on a toy generator: a lit sphere cap whose albedo carries the
    attributes (a dark mouth band = smiling, ...); ``sample`` re-renders with overrides."""

    R = 16

    def __init__(self, split="train", resolution=16, seed=0, size=None):
        self.split, self.seed, self.n = split, seed, size or 24

    def __len__(self):
        return self.n

    def sample(self, index, sh=None, **overrides):
        g = torch.Generator().manual_seed(hash((self.split, index, self.seed)) % 2**31)
        normal, matte, albedo, bg = (t[0].float() for t in ground_truth_scene(1, self.R, self.R, seed=index))
        strengths = {a: float(torch.rand(1, generator=g) > 0.5) for a in ("smiling", "beard", "eyeglasses", "senior")}
        if self.split.startswith("pool_"):
            strengths[self.split[5:]] = float(index % 2)
        strengths.update(overrides)
        for i, a in enumerate(strengths):
            albedo[i % 3, 3 + 3 * i : 5 + 3 * i, 4:12] *= 1 - 0.7 * strengths[a]
        if sh is None:
            d = torch.randn(1, 3, generator=g) + torch.tensor([0, 0, 2.0])
            sh = sh_from_directions(d, torch.full((1, 3), 0.6), 0.3)
        sh = torch.as_tensor(sh).reshape(1, 3, 9).float()
        shading = sh_shading(normal[None], sh)[0]
        return {
            "image": composite(matte, albedo * shading, bg).clamp(0, 1),
            "background": bg,
            "matte": matte,
            "mask_face": matte * (torch.arange(self.R) >= 5)[:, None],  # the head less its top rows: no hair
            "normal": normal,
            "albedo": albedo,
            "shading": shading,
            "sh": sh[0],
            "attrs": {
                **{a: torch.tensor(v) for a, v in strengths.items()},
                **{f"{a}_strength": torch.tensor(v) for a, v in strengths.items()},
            },
            "identity": torch.tensor(index % 5),
            "pose": torch.zeros(3),
        }

    def __getitem__(self, index):
        return self.sample(index)

    def get_batch(self, indices, **overrides):
        from disent.data import collate

        return collate([self.sample(i, **overrides) for i in indices])

    def params(self, indices):
        return {"alpha": torch.tensor(indices, dtype=torch.float32)[:, None] % 5, "skin": torch.ones(len(indices), 3)}


def test_edit_and_relight_tables_run_end_to_end_on_a_toy_generator():
    from disent.edit.classifier import MeasureNet
    from disent.edit.measure import claim_summary, edit_table, relight_table
    from disent.models import build_model

    torch.manual_seed(0)
    model = build_model({"name": "implicit", "resolution": 16, "code_dim": 8}).eval()
    net = MeasureNet(16, width=4, identity_dim=3).eval()
    rows, shown = edit_table(
        model,
        net,
        FakeSynth,
        "smiling",
        pool_size=12,
        n_sources=3,
        lambdas=(0.1, 0.03),
        alphas=(1.0,),
        resolution=16,
        truth_override=lambda a: {a: 1.0},
    )
    recon = rows[0]
    assert recon["method"] == "reconstruction" and recon["gain"] == 0 and recon["leakage"] == 0
    assert rows[1]["method"] == "truth" and rows[1]["d_bg"] == 0  # the true edit leaves the background alone
    drawn = rows[2]  # the model's reconstruction of the true edit: read against the input, like the truth
    assert drawn["method"] == "truth reconstructed" and 0 <= drawn["success"] <= 1
    # paper choice (UV+Ni), UV, Ni, Ai, all  x  (2 lambdas + 1 alpha)
    assert len(rows) == 3 + 5 * 3
    assert all(math.isfinite(r[k]) for r in rows for k in ("success", "gain", "leakage"))
    assert shown[("paper:UV+Ni", "dmt", 0.03)].shape == (3, 3, 16, 16)
    bary = [r for r in rows if r["method"] == "barycenter"]
    assert all(r["step"] == pytest.approx(1.0, rel=1e-4) for r in bary)  # alpha = 1 moves one mean difference
    claims = claim_summary(rows[3:])
    assert len(claims) == 2 * 5 and {c["method"] for c in claims} == {"dmt", "barycenter"}
    assert sorted(c["rank"] for c in claims if c["method"] == "dmt") == [1, 2, 3, 4, 5]
    # every edit row says how much of the true change it draws, over the image and in the face region; the claims
    # sum each over the strengths per leakage. FakeSynth's smile lies above its face region (the toy's "hair"): in
    # the face it changes nothing to draw
    assert all(math.isfinite(r["drawn_share"]) and math.isnan(r["drawn_share_face"]) for r in rows[2:])
    beard, _ = edit_table(
        model, net, FakeSynth, "beard", 12, 3, (0.1,), (1.0,), resolution=16, truth_override=lambda a: {a: 1.0}
    )
    for table in (rows, beard):
        for key, suffix in (("drawn_share", ""), ("drawn_share_face", "_face")):
            for c in claim_summary(table[3:]):
                rs = [r for r in table[3:] if r["method"] == c["method"] and r["manifolds"] == c["manifolds"]]
                per_leak = sum(r[key] for r in rs) / sum(r["leakage"] for r in rs)
                assert c[f"drawn{suffix}_per_leak"] == pytest.approx(per_leak, nan_ok=True)
                assert c[f"best_drawn{suffix}"] == pytest.approx(max(r[key] for r in rs), nan_ok=True)
                # and with no reader: per unit of the summed off-target change
                per_off = sum(r[key] for r in rs) / sum(r[f"off_target{suffix}"] for r in rs)
                assert c[f"drawn{suffix}_per_off_target"] == pytest.approx(per_off, nan_ok=True)
    # the share of the true change inside the face region: none of the smile, all of the beard
    assert rows[1]["change_in_face"] == 0.0 and beard[1]["change_in_face"] == pytest.approx(1.0)
    # the beard's change lies inside the face region, so there the two readings agree
    assert all(r["drawn_share_face"] == pytest.approx(r["drawn_share"], rel=1e-4) for r in beard[2:])
    no_truth, _ = edit_table(model, net, FakeSynth, "smiling", pool_size=12, n_sources=3, lambdas=(0.1,), alphas=())
    assert not any("drawn_share" in r or "drawn_share_face" in r for r in no_truth)
    assert not {"drawn_per_leak", "drawn_face_per_leak"} & set(claim_summary(no_truth[1:])[0])
    bank = {
        "left": sh_from_directions(torch.tensor([[-1.0, 0, 1]]), torch.full((1, 3), 0.6), 0.2),
        "right": sh_from_directions(torch.tensor([[1.0, 0.2, 1]]), torch.full((1, 3), 0.6), 0.2),
    }
    rel, example = relight_table(model, FakeSynth, bank, n_faces=2, n_lights=2, resolution=16)
    by = {r["method"]: r for r in rel}
    assert set(by) == {"transfer", "ratio", "decode", "input", "oracle"}
    assert by["oracle"]["psnr"] == 100.0  # the transfer formulas on true intrinsics: exact up to float32
    assert by["oracle"]["psnr_skin"] == 100.0 and 0 < by["input"]["psnr_skin"] < 100  # also inside the face region
    # one brightness scale per image (least squares, then clipped to the truth's range) can only bring it closer
    assert all(r["psnr_skin_scaled"] >= r["psnr_skin"] - 1e-9 for r in rel) and by["oracle"]["psnr_skin_scaled"] == 100
    # the face region split by the model's matte: one share for every method; a part with no pixel scores NaN
    share = by["transfer"]["matte_full_share"]
    assert 0 <= share <= 1 and all(r["matte_full_share"] == share for r in rel)
    for key, empty in (("psnr_skin_full_scaled", share == 0), ("psnr_skin_soft_scaled", share == 1)):
        assert all(math.isnan(r[key]) == empty for r in rel)
    assert example["transfer"].shape == (2, 3, 16, 16)


def test_what_a_perfect_autoencoder_draws_reads_as_the_truth_does():
    """The ``truth reconstructed`` row bounds an edit by what the model can draw: for a model that reconstructs
    exactly it reads as the truth itself."""
    from disent.edit.classifier import MeasureNet
    from disent.edit.measure import edit_table
    from disent.models import build_model

    class Exact(torch.nn.Module):  # the implicit model's codes, and the input itself as the reconstruction
        def __init__(self):
            super().__init__()
            self.inner = build_model({"name": "implicit", "resolution": 16, "code_dim": 8}).eval()
            self.CODE_NAMES = self.inner.CODE_NAMES

        def encode(self, x):
            self.last = x
            return self.inner.encode(x)

        def decode(self, codes):
            return {"recon": self.last}

    torch.manual_seed(0)
    net = MeasureNet(16, width=4, identity_dim=3).eval()
    rows, _ = edit_table(
        Exact(), net, FakeSynth, "beard", 12, 3, (0.1,), (1.0,), resolution=16, truth_override=lambda a: {a: 1.0}
    )
    truth, drawn = rows[1], rows[2]
    assert drawn["method"] == "truth reconstructed"
    assert drawn["success"] == truth["success"] and drawn["gain"] == pytest.approx(truth["gain"])
    assert drawn["drawn_share"] == pytest.approx(1.0)  # it draws all of the generator's change
    assert drawn["drawn_share_face"] == pytest.approx(1.0)  # and all of it in the face region


def test_drawn_share_is_the_part_of_the_true_change_a_model_reproduces():
    """No change drawn: 0; half of it (and any change orthogonal to it besides): 0.5; all of it: 1; the same
    reconstruction shifted by a constant in both images changes nothing. Inside a region only the change there
    counts: a model that draws the change in the region and none outside draws all of it there."""
    from disent.edit.measure import drawn_share

    g = torch.Generator().manual_seed(0)
    off, change = torch.rand(4, 3, 8, 8, generator=g), 0.2 * torch.randn(4, 3, 8, 8, generator=g)
    on = off + change
    other = torch.randn(4, 3, 8, 8, generator=g)
    other -= (other * change).sum() / (change * change).sum() * change  # orthogonal to the true change
    assert drawn_share(off, off, off, on) == 0.0
    assert drawn_share(off, off + 0.5 * change + other, off, on) == pytest.approx(0.5, abs=1e-5)
    assert drawn_share(off + 0.3, on + 0.3, off, on) == pytest.approx(1.0, abs=1e-5)
    region = torch.zeros(4, 1, 8, 8)
    region[..., :3] = 1  # the three left columns: 3/8 of the pixels
    inside_only = off + change * region
    assert drawn_share(off, inside_only, off, on, region) == pytest.approx(1.0, abs=1e-5)
    outside = (change * (1 - region)).pow(2).sum() / change.pow(2).sum()
    assert drawn_share(off, inside_only, off, on) == pytest.approx(1 - outside.item(), abs=1e-5)
    assert drawn_share(off, off + change * (1 - region), off, on, region) == 0.0


def test_off_target_share_is_the_change_not_along_the_true_change():
    """No change, or any multiple of the true change: no off-target change; a change orthogonal to it: its energy
    over the true change's; inside a region only the change there counts, and where the attribute changes nothing
    there the reading is NaN."""
    from disent.edit.measure import off_target_share

    g = torch.Generator().manual_seed(1)
    off, change = torch.rand(4, 3, 8, 8, generator=g), 0.2 * torch.randn(4, 3, 8, 8, generator=g)
    on = off + change
    other = torch.randn(4, 3, 8, 8, generator=g)
    other -= (other * change).sum() / (change * change).sum() * change  # orthogonal to the true change
    energy = (change * change).sum().item()
    assert off_target_share(off, off, off, on) == 0.0
    assert off_target_share(off, off + 2.5 * change, off, on) == pytest.approx(0.0, abs=1e-9)
    expected = (other * other).sum().item() / energy
    assert off_target_share(off, off + 0.5 * change + other, off, on) == pytest.approx(expected, rel=1e-4)
    region = torch.zeros(4, 1, 8, 8)
    region[..., :3] = 1
    outside = other * (1 - region)  # a change only outside the region is off target only over the whole image
    assert off_target_share(off, off + change + outside, off, on, region) == pytest.approx(0.0, abs=1e-9)
    assert off_target_share(off, off + change + outside, off, on) > 0
    assert math.isnan(off_target_share(off, off + other, off, off + change * (1 - region), region))


# ----------------------------------------------------------------------------- command line
def tiny_checkpoint(tmp_path, name="implicit"):
    from disent.models import build_model

    torch.manual_seed(0)
    cfg = {"model": {"name": name, "resolution": 16, "code_dim": 8}}
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    torch.save({"cfg": cfg, "model": build_model(cfg["model"]).state_dict()}, run / "checkpoints" / "last.pt")
    return run


def test_relight_command_writes_pngs_for_a_folder(tmp_path):
    from PIL import Image

    from disent.edit.__main__ import load_image, main

    run = tiny_checkpoint(tmp_path)
    photos = tmp_path / "photos"
    photos.mkdir()
    g = torch.Generator().manual_seed(0)
    for i in range(2):  # non-square, larger than the model, no face: centre-cropped (--no-align) and resized
        arr = (torch.rand(24, 20, 3, generator=g) * 255).byte().numpy()
        Image.fromarray(arr).save(photos / f"p{i}.png")
    assert load_image(photos / "p0.png", 16, align=False).shape == (3, 16, 16)
    out = tmp_path / "relit"
    main(
        [
            "relight",
            str(run),
            str(photos),
            "--direction",
            "0.5",
            "0.3",
            "0.8",
            "--method",
            "transfer",
            "ratio",
            "decode",
            "--out",
            str(out),
            "--no-align",
        ]
    )
    names = sorted(p.name for p in out.glob("*.png"))
    assert len(names) == 2 * 4 and "p0_transfer_dir_0.5_0.3_0.8.png" in names
    assert (out / ".tool").read_text() == "edit\n" and (out / "git.txt").exists()  # a tool folder (disent.runs)
    assert Image.open(out / "p1_relight_dir_0.5_0.3_0.8_strip.png").size == (6 * 16 + 5 * 2, 16)
    # the models read a photo decoded to linear radiance, and its pictures are written back sRGB-encoded: the strip's
    # input tile is the stored crop again, to within rounding
    from disent.data.photos.pseudo_gt import PseudoGTSettings, aligned_crop

    crop, _ = aligned_crop(photos / "p1.png", PseudoGTSettings(resolution=16), False)
    tile = np.asarray(Image.open(out / "p1_relight_dir_0.5_0.3_0.8_strip.png").convert("RGB"))[:, :16]
    assert np.abs(tile.astype(int) - crop.astype(int)).max() <= 1
    with pytest.raises(SystemExit):
        main(["relight", str(run), str(tmp_path / "missing.png"), "--direction", "0", "0", "1"])


def test_traverse_command_writes_a_lambda_strip(tmp_path, monkeypatch):
    from PIL import Image

    import disent.data
    from disent.edit.__main__ import main

    monkeypatch.setattr(disent.data, "SynthFaces", FakeSynth, raising=False)
    run = tiny_checkpoint(tmp_path)
    out = tmp_path / "edits"
    main(
        [
            "traverse",
            str(run),
            "synth:0",
            "synth:3",
            "--attribute",
            "beard",
            "--strength",
            "0.07",
            "0.03",
            "--pool-size",
            "12",
            "--out",
            str(out),
        ]
    )
    strip = out / "synth00003_add_beard_Ai_dmt_strip.png"
    assert strip.exists() and Image.open(strip).size == (4 * 16 + 3 * 2, 16)
    assert (out / "synth00000_add_beard_Ai_dmt_lam0.03.png").exists()
    main(
        [
            "traverse",
            str(run),
            "synth:0",
            "--attribute",
            "smiling",
            "--manifolds",
            "Ai",
            "UV",
            "--method",
            "barycenter",
            "--strength",
            "1",
            "--remove",
            "--pool-size",
            "12",
            "--out",
            str(out),
        ]
    )
    assert (out / "synth00000_remove_smiling_Ai+UV_barycenter_alpha1.png").exists()


def test_transfer_on_synthfaces_truth_reproduces_the_generators_relit_render():
    from disent.data import LIGHT_BANK, SynthFaces
    from disent.eval.metrics import reconstruction_metrics

    data = SynthFaces("test", size=4)
    b = data.get_batch(range(4))
    for name in ("flash_az-90", "overcast"):
        sh = torch.as_tensor(LIGHT_BANK[name]).float()
        truth = data.get_batch(range(4), sh=sh)["image"]
        out = transfer_lighting(
            b["image"], b["normal"], b["shading"], b["matte"], sh[None].expand(4, -1, -1), b["albedo"]
        )
        assert (out.clamp(0, 1) - truth).abs().max() < 1e-5
        naive = ratio_relight(b["image"], b["normal"], b["sh"], sh[None].expand(4, -1, -1))
        assert reconstruction_metrics(naive.clamp(0, 1), truth)["psnr"] < 60  # relights the background too


def test_measure_command_names_a_run_folders_results_by_seed_and_steps(tmp_path, monkeypatch):
    """``python -m disent.edit measure RUN_FOLDER --no-figures`` (toy generator, tiny model and measuring net):
    the results go to <model>_seed<seed>_<steps>steps/ with the run's setting in edit.json, and no figures."""
    import json

    import disent.data
    from disent.edit.__main__ import main
    from disent.edit.classifier import MeasureNet, save_measure_net

    monkeypatch.setattr(disent.data, "SynthFaces", FakeSynth)
    monkeypatch.setattr(
        disent.data,
        "LIGHT_BANK",
        {"left": sh_from_directions(torch.tensor([[-1.0, 0, 1]]), torch.full((1, 3), 0.6), 0.2)},
    )
    run = tiny_checkpoint(tmp_path, "explicit")
    ckpt = torch.load(run / "checkpoints" / "last.pt")
    ckpt["cfg"]["seed"], ckpt["step"] = 2, 7
    torch.save(ckpt, run / "checkpoints" / "last.pt")
    (run / ".hydra").mkdir()
    (run / ".hydra" / "overrides.yaml").write_text("- model=explicit\n- seed=2\n- train.lr=0.002\n")
    save_measure_net(MeasureNet(16, width=4, identity_dim=3), tmp_path / "m.pt")
    out = tmp_path / "out"
    main(
        ["measure", str(run), "--out", str(out), "--measure-net", str(tmp_path / "m.pt"), "--pool-size", "12"]
        + ["--sources", "2", "--lambdas", "0.1", "--alphas", "1.0", "--attributes", "smiling", "--relight-faces", "2"]
        + ["--no-figures"]
    )
    (folder,) = out.glob("explicit_seed2_7steps_*")  # a tag of the run folder's path: two runs never share a folder
    res = json.loads((folder / "edit.json").read_text())
    assert (res["model"], res["seed"], res["steps"], res["setting"]) == ("explicit", 2, 7, "train.lr=0.002")
    assert res["run"] == str(run.resolve())
    assert res["claims"] and res["relight"] and not list(folder.glob("*.png"))


def test_background_manifold_sets_are_a_separate_diagnostic():
    """``background=True`` adds the background code alone and with every face code, for the two rendering models
    only; the default sets never move it (the paper's traversal edits the face)."""
    from disent.edit.measure import manifold_choices

    for kind, face in (("explicit", ("Ne", "Ae")), ("implicit", ("UV", "Ni", "Ai"))):
        plain, more = manifold_choices(kind, "senior"), manifold_choices(kind, "senior", background=True)
        assert all("bg" not in ms for ms in plain.values())
        assert more == plain | {"bg": ("bg",), "all+bg": (*face, "bg")}
    assert manifold_choices("baseline", "senior", background=True) == manifold_choices("baseline", "senior")
