"""The three models, the EBGAN discriminator and every loss term, on a small synthetic batch."""

from pathlib import Path

import pytest
import torch
import torch.nn.functional as F
from hydra import compose, initialize_config_dir

from disent import losses as L
from disent.models import Discriminator, build_model
from disent.models.implicit import sample_uv
from disent.render import composite, image_formation, sh_from_directions, sh_shading
from disent.train import train_step

CONF = str(Path(__file__).resolve().parents[1] / "conf")
ABLATIONS = sorted(p.stem for p in (Path(CONF) / "ablation").glob("*.yaml"))
R = 16  # small resolution keeps these tests fast; the networks only need a multiple of 8


def fake_batch(B=4, H=R, seed=0):
    """A batch with the keys of SynthFaces, rendered from a sphere-cap face on a noisy background."""
    g = torch.Generator().manual_seed(seed)
    ys, xs = torch.meshgrid(torch.linspace(1, -1, H), torch.linspace(-1, 1, H), indexing="ij")
    r2 = xs**2 + ys**2
    mask = (r2 < 0.7).float().expand(B, 1, H, H).contiguous()
    normal = torch.stack([xs, ys, (1 - r2).clamp_min(0).sqrt()]).expand(B, 3, H, H) * mask
    normal = F.normalize(normal + 1e-12, dim=1) * mask
    albedo = (0.4 + 0.4 * torch.rand(B, 3, 1, 1, generator=g)).expand(B, 3, H, H)
    d = F.normalize(torch.randn(B, 1, 3, generator=g) * 0.5 + torch.tensor([0, 0, 1.0]), dim=-1)
    sh = sh_from_directions(d, torch.full((B, 1, 3), 0.6), 0.3)
    shading = sh_shading(normal, sh) * mask
    background = F.interpolate(torch.rand(B, 3, 4, 4, generator=g), size=(H, H), mode="bilinear", align_corners=True)
    image = composite(mask, image_formation(albedo, shading), background).clamp(0, 1)
    uv = torch.stack([xs, -ys]) * 0.5 + 0.5
    return {
        "image": image,
        "normal_pseudo": normal,
        "mask_pseudo": mask,
        "sh_pseudo": sh,
        "uv_pseudo": uv.expand(B, 2, H, H) * mask,
        "normal_uv_pseudo": normal.clone(),
    }


def model_cfg(name, **kw):
    return {"name": name, "resolution": R, **({"code_dim": 265} if name == "baseline" else {}), **kw}


def compose_cfg(*overrides):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


@pytest.mark.parametrize("name", ["baseline", "explicit", "implicit"])
def test_output_shapes_and_codes(name):
    torch.manual_seed(0)
    model = build_model(model_cfg(name))
    x = fake_batch()["image"]
    out = model(x)
    B = x.shape[0]
    assert out["recon"].shape == (B, 3, R, R)
    codes = {k: v for k, v in out["codes"].items() if k != "switches"}
    expected = {
        "baseline": {"z": 265},
        "explicit": dict(bg=128, m=128, L=27, Ne=128, Ae=128),
        "implicit": dict(bg=128, m=128, L=27, UV=128, Ni=128, Ai=128),
    }[name]
    assert {k: v.shape for k, v in codes.items()} == {k: (B, d) for k, d in expected.items()}
    if name != "baseline":
        for k in ("foreground", "background", "albedo", "shading", "normal"):
            assert out[k].shape == (B, 3, R, R), k
        assert out["matte"].shape == (B, 1, R, R) and out["sh"].shape == (B, 3, 9)
        torch.testing.assert_close(out["normal"].norm(dim=1), torch.ones(B, R, R))
        assert 0 <= out["matte"].min() and out["matte"].max() <= 1
        # the output is exactly the rendering of its parts (Eqs. 2-6)
        torch.testing.assert_close(out["shading"], sh_shading(out["normal"], out["sh"]))
        torch.testing.assert_close(
            out["recon"], composite(out["matte"], out["albedo"] * out["shading"], out["background"])
        )
        assert torch.equal(out["sh"], out["codes"]["L"].view(B, 3, 9))
    if name == "implicit":
        assert out["uv"].shape == (B, 2, R, R) and out["normal_uv"].shape == out["albedo_uv"].shape == (B, 3, R, R)
    torch.testing.assert_close(model.decode(model.encode(x))["recon"], out["recon"])


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="multiple of 8"):
        build_model(model_cfg("explicit", resolution=20))
    with pytest.raises(ValueError, match=r"\[B,3,16,16\]"):
        build_model(model_cfg("explicit"))(torch.rand(2, 3, 32, 32))
    with pytest.raises(ValueError, match="unknown model"):
        build_model(model_cfg("explicitt"))


def test_skips_reach_background_and_matte_only():
    """Sec. 3.3: only the bg and matte decoders see the pooling switches; the face goes through Z."""
    torch.manual_seed(0)
    model = build_model(model_cfg("explicit"))
    b = fake_batch()
    codes = model.encode(b["image"])
    other = model.encode(b["image"].flip(-1))["switches"]
    a, c = model.decode(codes), model.decode({**codes, "switches": other})
    for k in ("normal", "albedo", "shading", "foreground"):
        assert torch.equal(a[k], c[k]), k
    for k in ("background", "matte"):
        assert not torch.allclose(a[k], c[k]), k


def test_implicit_shares_the_Ni_Ai_decoder_and_samples_at_uv():
    torch.manual_seed(0)
    model = build_model(model_cfg("implicit"))
    codes = model.encode(fake_batch()["image"])
    out = model.decode({**codes, "Ai": codes["Ni"]})  # same code into the shared decoder: same raw map
    torch.testing.assert_close(
        F.normalize(torch.logit(out["albedo_uv"].double()), dim=1).float(), out["normal_uv"], atol=1e-4, rtol=0
    )
    torch.testing.assert_close(out["normal"], F.normalize(sample_uv(out["normal_uv"], out["uv"]), dim=1))
    # identity UV (u = column, v = row, texel centres at 0..1) reads the UV map back unchanged
    v, u = torch.meshgrid(torch.linspace(0, 1, R), torch.linspace(0, 1, R), indexing="ij")
    m = torch.rand(2, 3, R, R)
    torch.testing.assert_close(sample_uv(m, torch.stack([u, v]).expand(2, 2, R, R)), m)
    # a horizontal flip of the UV map flips the sampled image
    torch.testing.assert_close(sample_uv(m, torch.stack([1 - u, v]).expand(2, 2, R, R)), m.flip(-1))


def test_every_ablation_config_is_listed():
    assert {
        "no_bws",
        "no_smooth_a",
        "no_smooth_s",
        "no_smooth",
        "no_matting",
        "no_adv",
        "no_pseudo_normal",
        "no_pseudo_light",
    } <= set(ABLATIONS)


@pytest.mark.parametrize("ablation", ABLATIONS)
def test_ablation_removes_its_terms(ablation):
    """The ablated terms are absent, and the gradient is the full one minus exactly their contribution."""
    full = compose_cfg("model=implicit")
    abl = compose_cfg("model=implicit", f"+ablation={ablation}")
    w_full, w_abl = dict(full.loss.weights), dict(abl.loss.weights)
    removed = [t for t in L.TERMS if w_full[t] and not w_abl[t]]
    assert removed, f"{ablation} switches no term off"
    torch.manual_seed(0)  # float64: the check subtracts gradients of weighted sums (weights up to 7.5)
    model = build_model(model_cfg("implicit", matting=abl.model.matting)).double()
    D = Discriminator(R).double()
    b = {k: v.double() if torch.is_tensor(v) and v.is_floating_point() else v for k, v in fake_batch().items()}
    params = list(model.parameters())

    def grads(weights):
        out = model(b["image"])
        ls = L.generator_losses(out, b, weights, D.energy(out["recon"]) if weights.get("adv") else None)
        return ls, torch.autograd.grad(ls["total"], params, allow_unused=True)

    ls_abl, g_abl = grads(w_abl)
    ls_full, g_full = grads(w_full)
    for t in removed:
        assert t not in ls_abl and t in ls_full
    out = model(b["image"])
    ls_rem = L.generator_losses(
        out, b, {t: w_full[t] for t in removed}, D.energy(out["recon"]) if "adv" in removed else None
    )
    g_rem = (
        torch.autograd.grad(ls_rem["total"], params, allow_unused=True)
        if ls_rem["total"].requires_grad
        else [None] * len(params)
    )  # no_matting: E_M of a constant matte has no gradient at all
    zero = torch.zeros(())
    for ga, gf, gr, p in zip(g_abl, g_full, g_rem, params):
        ga, gf, gr = (g if g is not None else zero.expand_as(p) for g in (ga, gf, gr))
        torch.testing.assert_close(ga, gf - gr, atol=1e-12, rtol=1e-9)
    if abl.model.matting:
        assert any(g is not None and g.abs().sum() > 0 for g in g_rem)  # the removed terms did contribute
    else:  # no matting layer: the output is the rendered face everywhere
        out = model(b["image"])
        assert torch.equal(out["matte"], torch.ones_like(out["matte"])) and torch.equal(out["recon"], out["foreground"])


@pytest.mark.parametrize("name", ["explicit", "implicit"])
def test_the_supervised_ceiling_trains_on_the_true_layers_only(name):
    """loss=ceiling: the truth terms are the whole objective (closed forms: 0 at the truth, the mean square off
    it), the step reads the true layers, and Adam steps on one batch more than halve it."""
    from disent.train import TRAIN_KEYS, train_keys

    cfg = compose_cfg(f"model={name}", "loss=ceiling")
    assert train_keys(cfg.loss) == TRAIN_KEYS + L.TRUTH_KEYS and train_keys(compose_cfg().loss) == TRAIN_KEYS
    assert train_keys(compose_cfg("loss.recon_L_target=sh").loss) == TRAIN_KEYS + L.TRUTH_KEYS
    assert train_keys(compose_cfg("loss.recon_L_oracle_mix=0.5").loss) == TRAIN_KEYS + L.TRUTH_KEYS
    b = fake_batch(8)
    b.update(
        albedo=torch.full_like(b["image"], 0.5), normal=b["normal_pseudo"], sh=b["sh_pseudo"], matte=b["mask_pseudo"]
    )
    exact = {"albedo": b["albedo"], "normal": b["normal"], "sh": b["sh"]}
    assert L.generator_losses(exact, b, dict(cfg.loss.weights))["total"].item() == 0
    off = {"albedo": b["albedo"] + 0.1, "normal": b["normal"] + 0.2, "sh": b["sh"] + 0.3}
    losses = L.generator_losses(off, b, dict(cfg.loss.weights))
    assert set(losses) == {"A_true", "N_true", "L_true", "total"}
    assert [losses[k].item() for k in L.TRUTH] == pytest.approx([0.01, 0.04, 0.09], rel=1e-5)
    torch.manual_seed(0)
    model = build_model(model_cfg(name))
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    totals = [train_step(model, None, opt, None, b, cfg.loss)["total"].item() for _ in range(30)]
    assert totals[-1] < 0.5 * totals[0], totals


@pytest.mark.parametrize("name", ["baseline", "explicit", "implicit"])
def test_a_few_steps_on_one_batch_lower_the_loss(name):
    """Steps of the configured optimiser and learning rate on one fixed batch lower every model's objective
    (adversarial term off: D moves its target)."""
    from disent.optim import make_optimizer

    torch.manual_seed(0)
    cfg = compose_cfg(f"model={name}", "+ablation=no_adv")
    model = build_model(model_cfg(name))
    opt = make_optimizer(model, cfg.train)
    b = fake_batch(8)
    totals = [train_step(model, None, opt, None, b, cfg.loss)["total"].item() for _ in range(40)]
    assert totals[-1] < 0.8 * totals[0], totals


def test_early_weights_replace_a_terms_weight_for_the_first_steps_only():
    """``loss.early_weights`` trains a term at its early weight while step < ``loss.early_steps``, then at
    ``loss.weights``: with the model held still (lr 0), the objective at an early step exceeds a later one's by
    exactly the weight's difference times the term."""
    from disent.optim import loss_weights

    cfg = compose_cfg("model=implicit", "+ablation=no_adv", "+loss.early_weights.UV=50", "loss.early_steps=5")
    late = dict(cfg.loss.weights)
    assert late["UV"] != 50 and loss_weights(cfg.loss, 4) == {**late, "UV": 50} and loss_weights(cfg.loss, 5) == late
    assert loss_weights(compose_cfg("model=implicit").loss, 0) == dict(compose_cfg("model=implicit").loss.weights)
    torch.manual_seed(0)
    model = build_model(model_cfg("implicit")).eval()  # batch statistics fixed: the two passes see one model
    opt = torch.optim.SGD(model.parameters(), lr=0.0)
    b = fake_batch(4)
    early, later = (train_step(model, None, opt, None, b, cfg.loss, step) for step in (0, 5))
    assert early["UV"].item() == pytest.approx(later["UV"].item()) and later["UV"].item() > 0
    gap = early["total"].item() - later["total"].item()
    assert gap == pytest.approx((50 - late["UV"]) * later["UV"].item(), rel=1e-4)


def test_adversarial_step_updates_generator_and_discriminator_from_their_own_losses():
    torch.manual_seed(0)
    cfg = compose_cfg("model=explicit")
    model, D = build_model(model_cfg("explicit")), Discriminator(R)
    opt_g, opt_d = torch.optim.SGD(model.parameters(), lr=0.1), torch.optim.SGD(D.parameters(), lr=0.1)
    b = fake_batch()
    d0 = [p.detach().clone() for p in D.parameters()]
    # D's gradient must be that of its margin loss alone, with the generated image held fixed
    out = model(b["image"])
    d_loss = L.discriminator_loss(D.energy(b["image"]), D.energy(out["recon"].detach()), cfg.loss.margin)
    expected = torch.autograd.grad(d_loss, list(D.parameters()))
    losses = train_step(model, D, opt_g, opt_d, b, cfg.loss)
    assert {"recon", "adv", "D", "total"} <= set(losses)
    for p0, p, g in zip(d0, D.parameters(), expected):
        torch.testing.assert_close(p0 - 0.1 * g, p.detach(), atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("margin", [1e-9, 10.0])  # every generated image past the margin / inside it
def test_leaving_out_the_generated_batch_past_the_margin_changes_no_bit(monkeypatch, margin):
    """D's loss drops the generated batch when every image is past the margin; the step's
    updates of both networks are bitwise those of the plain EBGAN loss."""
    cfg = compose_cfg("model=explicit").loss
    cfg.margin = margin
    plain = lambda real, fake, m: real.mean() + F.relu(m - fake).mean()
    params = []
    for loss in (L.discriminator_loss, plain):
        torch.manual_seed(0)
        model, D = build_model(model_cfg("explicit")), Discriminator(R)
        opt_g, opt_d = torch.optim.SGD(model.parameters(), lr=0.1), torch.optim.SGD(D.parameters(), lr=0.1)
        monkeypatch.setattr(L, "discriminator_loss", loss)
        before = [p.detach().clone() for p in D.parameters()]
        train_step(model, D, opt_g, opt_d, fake_batch(), cfg)
        assert not all(torch.equal(a, b) for a, b in zip(before, D.parameters()))  # D did learn
        params.append([p.detach().clone() for p in (*model.parameters(), *D.parameters())])
    assert all(torch.equal(a, b) for a, b in zip(*params))


@pytest.mark.parametrize("name", ["baseline", "explicit", "implicit"])
def test_model_and_losses_hold_no_tensor_on_the_cpu(name, monkeypatch):
    """Forward and backward of a model, D and every generator loss term on the ``meta`` device (shapes,
    no data): an elementwise operation that meets a tensor made on the CPU (a constant without
    ``device=``) raises, as it would on a GPU; the stand-in for a CUDA run where there is no GPU.
    ``torch.autocast`` knows no meta device; here it does nothing."""
    import contextlib

    autocast = torch.autocast
    monkeypatch.setattr(
        torch,
        "autocast",
        lambda device_type, *a, **k: (
            contextlib.nullcontext() if device_type == "meta" else autocast(device_type, *a, **k)
        ),
    )
    cfg = compose_cfg(f"model={name}")
    model, disc = build_model(model_cfg(name)).to("meta"), Discriminator(R).to("meta")
    b = {k: v.to("meta") for k, v in fake_batch(2).items()}
    out = model(b["image"])
    losses = L.generator_losses(out, b, dict(cfg.loss.weights), disc.energy(out["recon"]), cfg.loss.bws_c)
    (losses["total"] + disc.energy(b["image"]).mean()).backward()  # (the margin loss reads its hinge on the host)
    assert all(v.device.type == "meta" for v in (*out.values(), *losses.values()) if torch.is_tensor(v))
    assert all(p.grad is not None and p.grad.device.type == "meta" for p in model.parameters())


def test_hemisphere_normals_are_unit_face_the_camera_and_start_frontal():
    """model.normal=xy (the release): unit length, n_z >= 0 everywhere, n_x and n_y pass through where
    n_x^2 + n_y^2 < 1, and a zero decoder output is the frontal normal (0, 0, 1)."""
    from disent.models.explicit import decode_normal

    raw = torch.randn(4, 2, 8, 8, dtype=torch.float64) * 2
    n = decode_normal(raw, "xy")
    torch.testing.assert_close(n.norm(dim=1), torch.ones(4, 8, 8, dtype=torch.float64))
    assert (n[:, 2] >= 0).all()
    inside = raw.clamp(-1, 1).pow(2).sum(1) < 0.9
    torch.testing.assert_close(n[:, :2].permute(1, 0, 2, 3)[:, inside], raw.permute(1, 0, 2, 3)[:, inside])
    torch.testing.assert_close(
        decode_normal(torch.zeros(1, 2, 2, 2), "xy"),
        torch.tensor([0.0, 0.0, 1.0])[None, :, None, None].expand(1, 3, 2, 2),
    )
    free = torch.randn(2, 3, 4, 4)
    torch.testing.assert_close(decode_normal(free, "unit"), F.normalize(free, dim=1))


def test_layer_choices_are_checked_and_shared_with_the_discriminator():
    from disent.models.networks import Layers
    from disent.optim import build_discriminator

    with pytest.raises(ValueError, match="model.norm='batchnorm'; choose from none, batch, group"):
        build_model(model_cfg("explicit", norm="batchnorm"))
    with pytest.raises(ValueError, match="model.normal='xyz'"):
        build_model(model_cfg("explicit", normal="xyz"))
    model = build_model(model_cfg("implicit", norm="group", centre_input=True, z_act="sigmoid"))
    assert model.layers == Layers("group", True, "sigmoid")
    D = build_discriminator(model)
    assert D.encoder.layers == model.layers and isinstance(D.decoder.norms[0], torch.nn.GroupNorm)
    z, _ = model.encoder(torch.rand(2, 3, R, R))
    assert ((z > 0) & (z < 1)).all()  # the release's sigmoid on Z_I


def test_a_deeper_decoder_adds_convolutions_without_skips_and_keeps_the_papers_weights():
    """``model.decoder_convs``: at 1 (the paper) the decoders hold the same weights under the same names as before
    it existed (shipped checkpoints load), and compute what the speed kernels compute; at 2 each decoder without
    skips gains one 3x3 convolution a stage (the last before its output convolution), the skip-connected
    background and matte decoders none, gradients reach every new weight, and the speed kernels step aside."""
    from disent.models.networks import CHANNELS, Layers
    from disent.optim import build_discriminator

    with pytest.raises(ValueError, match="model.decoder_convs=0"):
        build_model(model_cfg("baseline", decoder_convs=0))
    paper = build_model(model_cfg("explicit"))
    assert not any("extra" in k for k in paper.state_dict())
    torch.manual_seed(0)
    deep = build_model(model_cfg("explicit", decoder_convs=2))
    assert deep.layers == Layers(decoder_convs=2)
    widths = [[m.in_channels for m in stage] for stage in deep.dec_A.extra]
    assert widths == [[CHANNELS[1]], [CHANNELS[0]], [CHANNELS[0]]]  # 64, 32, then 32 before the 3-channel output
    assert not any(deep.dec_bg.extra) and not any(deep.dec_m.extra)
    assert any(build_discriminator(deep).decoder.extra)
    x = torch.rand(2, 3, R, R)
    out = deep(x)
    assert out["albedo"].shape == (2, 3, R, R)
    out["albedo"].sum().backward()
    assert all(c.weight.grad is not None and c.weight.grad.abs().sum() > 0 for s in deep.dec_A.extra for c in s)
    with torch.no_grad():  # the kernels path and the plain path agree at the paper's depth
        plain = build_model(model_cfg("baseline", kernels=False)).eval()
        fast = build_model(model_cfg("baseline", kernels=True)).eval()
        fast.load_state_dict(plain.state_dict())
        assert torch.allclose(plain(x)["recon"], fast(x)["recon"], atol=1e-5)
