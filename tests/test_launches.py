"""What a training step and a sampling call would launch on a GPU: the counter, and the step's host syncs."""

from __future__ import annotations

import pytest
import torch

from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy
from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.maths.geometry import device_code_paths, estimate_rigid_transform, farthest_point_sample
from lerobot_taxdpd.policies.taxdpd.model import pointnet2
from lerobot_taxdpd.policies.taxdpd.model.pointnet2 import make_encoder
from lerobot_taxdpd.reports.launches import LaunchCounter


def test_the_counter_counts_launches_and_reads_but_not_views():
    x = torch.randn(8, 3)
    counter = LaunchCounter()
    with counter:
        y = x.view(24).reshape(8, 3).transpose(0, 1)  # views: nothing launched
        z = (y + 1).relu()  # two kernels
        float(z.sum())  # a kernel and a read-back
        z[z > 0]  # a comparison kernel, and a shape that depends on the data
        z.tolist()
    assert counter.total_ops() == 5  # add, relu, sum, gt, index
    assert counter.syncs["other"] == {"_local_scalar_dense": 1, "index": 1, "tolist": 1}


def test_cpu_shortcuts_take_the_device_path_when_asked():
    points = torch.rand(2, 64, 3, generator=torch.Generator().manual_seed(0))
    counter = LaunchCounter()
    with counter:
        fast = farthest_point_sample(points, 8)
    assert counter.syncs  # the CPU path reads the clouds into numpy
    with device_code_paths():
        portable = farthest_point_sample(points, 8)
    torch.testing.assert_close(portable, fast)  # the same indices either way


def _small_policy(**overrides) -> TaxDPDPolicy:
    fields = dict(hidden_dim=16, num_blocks=1, num_heads=2, max_neighbors=8, use_ema=True, point_scale=20.0)
    config = TaxDPDConfig.for_point_clouds(32, 64, device="cpu", **(fields | overrides))
    return TaxDPDPolicy(config)


@pytest.mark.parametrize(
    "overrides", [{}, {"use_amp": True}, {"local_scene_points": 48}], ids=["fp32", "bf16", "local-scene"]
)
def test_a_training_step_never_waits_for_the_device_until_its_read_back(overrides):
    """Forward, backward, clipping, the optimiser and the weight average as lerobot-train runs them: no host sync
    until `update()` reads the step's loss terms and input checks back, once."""
    torch.manual_seed(0)
    policy = _small_policy(**overrides).train()
    optimizer = policy.config.get_optimizer_preset().build(policy.get_optim_params())
    g = torch.Generator().manual_seed(1)
    obj = torch.rand(4, 32, 3, generator=g) * 0.1
    batch = {OBJECT_KEY: obj, SCENE_KEY: torch.rand(4, 64, 3, generator=g), ACTION_KEY: obj + 0.3}

    def step(counter: LaunchCounter) -> dict:
        with counter.stage("step"):
            loss, terms = policy.forward(batch)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0, foreach=True)
            optimizer.step()
            optimizer.zero_grad()
        with counter.stage("read-back"):
            policy.update()
        return terms

    step(LaunchCounter())  # the first update reads the average's step count once
    counter = LaunchCounter()
    with device_code_paths(), counter:
        terms = step(counter)
    assert "step" not in counter.syncs, counter.syncs
    assert sum(counter.syncs["read-back"].values()) == 1
    assert counter.ops["step"]  # and the step did run
    assert all(isinstance(value, float) for value in terms.values())


def test_an_amp_step_casts_the_linear_weights_together_and_computes_the_same_step(monkeypatch):
    """Under AMP the training pass runs on the linear layers' bf16 weights cast in one op, not one cast a layer
    each way: the loss and every fp32 gradient must be the ones autocast's own casts give, bit for bit."""
    policy = _small_policy(use_amp=True, num_blocks=2).train()
    g = torch.Generator().manual_seed(5)
    obj = torch.rand(4, 32, 3, generator=g) * 0.1
    batch = {OBJECT_KEY: obj, SCENE_KEY: torch.rand(4, 64, 3, generator=g), ACTION_KEY: obj + 0.3}

    def step(counter: LaunchCounter) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        torch.manual_seed(6)  # the same augmentations, noise and timesteps in both steps
        policy.zero_grad(set_to_none=True)
        with counter:
            loss, _ = policy.forward(batch)
            loss.backward()
        policy.update()
        return loss.detach(), {name: p.grad for name, p in policy.named_parameters() if p.grad is not None}

    together = LaunchCounter()
    loss, grads = step(together)
    # The reference: autocast casting each linear layer's weights itself.
    monkeypatch.setattr(policy, "_training_call", lambda *args, **kwargs: policy.model(*args, **kwargs))
    per_layer = LaunchCounter()
    reference_loss, reference_grads = step(per_layer)

    assert torch.equal(loss, reference_loss)
    assert grads.keys() == reference_grads.keys() == dict(policy.model.named_parameters(prefix="model")).keys()
    for name, grad in grads.items():
        assert grad.dtype == torch.float32 and torch.equal(grad, reference_grads[name]), name
    casts = {name: sum(c["_to_copy"] for c in counter.ops.values()) for name, counter in (
        ("together", together), ("per layer", per_layer))}  # fmt: skip
    linear_layers = sum(isinstance(m, torch.nn.Linear) for m in policy.model.modules())
    assert casts["per layer"] - casts["together"] >= 3 * linear_layers, casts


def test_a_point_encoder_under_autocast_casts_its_clouds_once():
    """Coordinates cast once to the layers' dtype, not at every concatenation with bf16 features: with a grouping
    cast once for the passes that reuse it, one cast a pass (the cloud); with a fresh fp32 one, five (the cloud,
    both levels' centroids, the two interpolation weights, each in place of the gather it replaces); the same
    features either way and as the clouds handed over in bf16."""
    encoder = make_encoder(_small_policy().config, in_channels=9).to(torch.bfloat16)  # bf16 weights, as sampling has
    g = torch.Generator().manual_seed(3)
    xyz, features = torch.rand(2, 32, 3, generator=g), torch.rand(2, 32, 9, generator=g)
    layout = encoder.layout([xyz])
    casts = {}
    with torch.autocast("cpu", dtype=torch.bfloat16), torch.no_grad():
        grouping = encoder.group(xyz, layout)
        outputs = {}
        for name, given in {"fresh": grouping, "cast": grouping.cast(encoder.compute_dtype(xyz))}.items():
            counter = LaunchCounter()
            with counter:
                outputs[name] = encoder(xyz, features, layout=layout, grouping=given)
            casts[name] = sum(c["_to_copy"] for c in counter.ops.values())
        handed_bf16 = encoder(xyz.bfloat16(), features.bfloat16(), layout=layout, grouping=grouping)
    assert casts == {"fresh": 5, "cast": 1}
    assert outputs["cast"].dtype == torch.bfloat16
    assert torch.equal(outputs["cast"], outputs["fresh"]) and torch.equal(outputs["cast"], handed_bf16)


def test_the_object_is_grouped_once_for_both_stages(monkeypatch):
    """Both stages' object encoders and the deformation encoder see the same centred object with the same layout,
    so one grouping (distances, neighbourhoods, weights: about 24 launches) serves them all: a training step groups
    three clouds (the object, the GMM's scene, the reconstruction cloud), a sampling call the object and the scene
    once and the reconstruction cloud at each of its denoising steps."""
    built = []
    build = pointnet2.build_grouping
    monkeypatch.setattr(pointnet2, "build_grouping", lambda xyz, *args: built.append(xyz.shape) or build(xyz, *args))
    policy = _small_policy().train()
    g = torch.Generator().manual_seed(1)
    obj = torch.rand(4, 32, 3, generator=g) * 0.1
    policy.forward({OBJECT_KEY: obj, SCENE_KEY: torch.rand(4, 64, 3, generator=g), ACTION_KEY: obj + 0.3})
    assert len(built) == 3, built
    built.clear()
    policy.eval().sample_goals(obj[:1], torch.rand(1, 64, 3, generator=g), 10)
    assert len(built) == 2 + policy.config.num_inference_steps, built


@pytest.mark.parametrize("overrides", [{}, {"local_scene_points": 48}], ids=["whole-scene", "local-scene"])
def test_sampling_reads_back_at_most_twice(overrides):
    """The input checks (values, units) are the only reads: the denoising loop waits for nothing."""
    policy = _small_policy(**overrides).eval()
    g = torch.Generator().manual_seed(2)
    counter = LaunchCounter()
    with device_code_paths(), counter:
        policy.sample_goals(torch.rand(1, 32, 3, generator=g) * 0.1, torch.rand(1, 64, 3, generator=g), 10)
    assert counter.total_syncs() <= 2, counter.syncs


def test_poses_read_the_inputs_once_more_than_the_fit_needs():
    """`predict_poses` checks its clouds once: its reads are sampling's plus RANSAC-SVD's own."""
    policy = _small_policy().eval()
    g = torch.Generator().manual_seed(2)
    obj, scene = torch.rand(1, 32, 3, generator=g) * 0.1, torch.rand(1, 64, 3, generator=g)
    goals = policy.sample_goals(obj, scene, 10)
    counts = {}
    for name, call in {
        "poses": lambda: policy.predict_poses(obj, scene, 10),
        "sampling": lambda: policy.sample_goals(obj, scene, 10),
        "fit": lambda: estimate_rigid_transform(
            obj.unsqueeze(1).expand_as(goals), goals, threshold=policy.config.ransac_threshold
        ),
    }.items():
        counter = LaunchCounter()
        with device_code_paths(), counter:
            call()
        counts[name] = counter.total_syncs()
    assert counts["poses"] == counts["sampling"] + counts["fit"], counts


@pytest.mark.slow
def test_a_compiled_policy_trains_samples_and_keeps_the_weights_names():
    """compile_mode compiles the DiTs in place: a checkpoint of either kind loads into the other."""
    eager, compiled = _small_policy(), _small_policy(compile_mode="default")
    assert eager.state_dict().keys() == compiled.state_dict().keys()
    compiled.load_state_dict(eager.state_dict())
    g = torch.Generator().manual_seed(3)
    obj, scene = torch.rand(2, 32, 3, generator=g) * 0.1, torch.rand(2, 64, 3, generator=g)
    for policy in (eager, compiled):
        policy.eval()
    same = [p.sample_goals(obj, scene, 2, generator=torch.Generator().manual_seed(4)) for p in (eager, compiled)]
    torch.testing.assert_close(same[1], same[0], rtol=1e-4, atol=1e-5)
    compiled.train()
    loss, _ = compiled.forward({OBJECT_KEY: obj, SCENE_KEY: scene, ACTION_KEY: obj + 0.3})
    loss.backward()
    assert all(p.grad is not None for p in compiled.model.parameters())


def test_an_unknown_compile_mode_is_refused_by_name():
    with pytest.raises(ValueError, match="compile_mode"):
        TaxDPDConfig(compile_mode="fast")
