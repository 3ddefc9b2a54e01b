"""The `taxdpd` policy's public API, inputs checks, saving/loading and processors (untrained, tiny model)."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.processor import PolicyProcessorPipeline

from conftest import install_in_hub_cache
from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy, load_goal_predictor, make_taxdpd_pre_post_processors
from lerobot_taxdpd.apps.synthetic import write_slot_dataset
from lerobot_taxdpd.data.scaling import SCALE_FILE
from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.data.validation import PointCloudError
from lerobot_taxdpd.policies.mixed_precision import cpu_bf16_speedup
from lerobot_taxdpd.sim.pretrain import save_shipped
from lerobot_taxdpd.sim.tasks import get_task
from lerobot_taxdpd.sim.trials import make_trial

N_O, N_S = 32, 64


def tiny_policy(**overrides) -> TaxDPDPolicy:
    torch.manual_seed(0)
    config = TaxDPDConfig.for_point_clouds(
        N_O,
        N_S,
        hidden_dim=16,
        num_blocks=1,
        num_heads=2,
        point_scale=20.0,
        num_inference_steps=2,
        device="cpu",
        **overrides,
    )
    return TaxDPDPolicy(config).eval()


def clouds(batch: int = 2, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(batch, N_O, 3, generator=g) * 0.1, torch.rand(batch, N_S, 3, generator=g)


def test_point_scale_comes_from_the_dataset_metadata_or_a_scan_of_datasets_made_elsewhere(tmp_path):
    root = write_slot_dataset(tmp_path / "slots", episodes=3, object_cloud_size=N_O, scene_cloud_size=N_S)
    config = dict(hidden_dim=16, num_blocks=1, num_heads=2, object_scale=3.0, device="cpu")
    stats = json.loads((root / SCALE_FILE).read_text())
    written = TaxDPDPolicy(
        TaxDPDConfig.for_point_clouds(N_O, N_S, **config), dataset_meta=LeRobotDatasetMetadata("local/slots", root=root)
    )
    assert written.config.point_scale == pytest.approx(3.0 / stats["median_object_radius"])
    # The metadata, not the data, is what is read: a recorded radius of 0.5 m gives 3 / 0.5 model units a metre.
    (root / SCALE_FILE).write_text(json.dumps({**stats, "median_object_radius": 0.5}))
    recorded = TaxDPDPolicy(
        TaxDPDConfig.for_point_clouds(N_O, N_S, **config), dataset_meta=LeRobotDatasetMetadata("local/slots", root=root)
    )
    assert recorded.config.point_scale == pytest.approx(6.0)
    (root / SCALE_FILE).unlink()
    scanned = TaxDPDPolicy(
        TaxDPDConfig.for_point_clouds(N_O, N_S, **config), dataset_meta=LeRobotDatasetMetadata("local/slots", root=root)
    )
    assert scanned.config.point_scale == written.config.point_scale


def test_public_api_shapes_and_frames():
    policy = tiny_policy()
    obj, scene = clouds()
    goals = policy.sample_goals(obj, scene, num_samples=3)
    assert goals.shape == (2, 3, N_O, 3) and goals.dtype == torch.float32
    poses = policy.predict_poses(obj, scene, num_samples=2)
    assert poses.shape == (2, 2, 4, 4)
    rotations = poses[..., :3, :3].double()
    assert torch.allclose(rotations @ rotations.transpose(-1, -2), torch.eye(3, dtype=torch.float64), atol=1e-5)
    weights, means = policy.placement_distribution(obj, scene)
    assert weights.shape == (2, N_S) and means.shape == (2, N_S, 3)
    assert torch.allclose(weights.sum(-1), torch.ones(2), atol=1e-5)
    # Means live in the caller's frame: an untrained GMM puts them on (or very near) the scene points.
    assert (means - scene).norm(dim=-1).median() < 0.5


def test_sampling_is_reproducible_with_a_generator_and_translation_equivariant_in_frame():
    policy = tiny_policy()
    obj, scene = clouds()
    first = policy.sample_goals(obj, scene, 2, generator=torch.Generator().manual_seed(3))
    second = policy.sample_goals(obj, scene, 2, generator=torch.Generator().manual_seed(3))
    assert torch.equal(first, second)
    shift = torch.tensor([10.0, -4.0, 2.0])
    moved = policy.sample_goals(obj + shift, scene + shift, 2, generator=torch.Generator().manual_seed(3))
    assert torch.allclose(moved - shift, first, atol=1e-3)  # works in the scene's own frame


def test_given_placement_frames_replace_the_dense_gmm_and_move_with_the_scene():
    policy = tiny_policy()
    obj, scene = clouds()
    frames = scene.mean(1) + torch.tensor([0.05, 0.0, 0.02])
    seeded = dict(generator=torch.Generator().manual_seed(3), placement_frames=frames)
    first = policy.sample_goals(obj, scene, 2, **seeded)
    shift = torch.tensor([10.0, -4.0, 2.0])
    seeded = dict(generator=torch.Generator().manual_seed(3), placement_frames=frames + shift)
    torch.testing.assert_close(policy.sample_goals(obj + shift, scene + shift, 2, **seeded) - shift, first, atol=1e-3,
                               rtol=0)  # fmt: skip
    with torch.no_grad():  # a broken GMM no longer matters: the frames are given
        for parameter in policy.model.global_stage.parameters():
            parameter.fill_(float("nan"))
    assert torch.isfinite(policy.sample_goals(obj, scene, 2, placement_frames=frames)).all()
    assert torch.isfinite(policy.predict_poses(obj, scene, 2, placement_frames=frames)).all()
    with pytest.raises(RuntimeError, match="multinomial"):  # and without frames, the GMM is what samples them
        policy.sample_goals(obj, scene, 2)
    with pytest.raises(PointCloudError, match=r"placement_frames: expected shape \(2, 3\), one per scene"):
        policy.sample_goals(obj, scene, 1, placement_frames=frames[:1])
    with pytest.raises(PointCloudError, match="placement_frames: NaN or infinite"):
        policy.predict_poses(obj, scene, 1, placement_frames=frames * float("nan"))


def test_clouds_denser_than_the_network_are_reduced_and_answered_for_every_point():
    policy = tiny_policy()  # the network sees N_O / N_S points
    g = torch.Generator().manual_seed(5)
    obj, scene = torch.rand(1, 4 * N_O, 3, generator=g) * 0.1, torch.rand(1, 3 * N_S, 3, generator=g)
    goals = policy.sample_goals(obj, scene, 3, generator=torch.Generator().manual_seed(0))
    assert goals.shape == (1, 3, 4 * N_O, 3) and bool(torch.isfinite(goals).all())
    weights, means = policy.placement_distribution(obj, scene)
    assert weights.shape == (1, 3 * N_S) and means.shape == (1, 3 * N_S, 3)
    torch.testing.assert_close(weights.sum(-1), torch.ones(1))
    poses = policy.predict_poses(obj, scene, 2, generator=torch.Generator().manual_seed(0))
    assert poses.shape == (1, 2, 4, 4)


@pytest.mark.parametrize(
    ("obj", "scene", "message"),
    [
        (torch.rand(N_O, 3), torch.rand(1, N_S, 3), "object_points: expected a batch"),
        (torch.rand(1, N_O, 3), torch.rand(2, N_S, 3), "batch sizes 1 and 2 differ"),
        (torch.full((1, N_O, 3), float("nan")), torch.rand(1, N_S, 3), "object_points: contains"),
        (torch.rand(1, N_O, 3), torch.rand(1, N_S, 3) * float("inf"), "scene_points: contains"),
        (torch.rand(1, 0, 3), torch.rand(1, N_S, 3), "object_points: is empty"),
        (torch.rand(1, 2, 3), torch.rand(1, N_S, 3), "object_points: has 2 points"),
        (torch.rand(1, N_O, 2), torch.rand(1, N_S, 3), "object_points: expected shape"),
        (torch.rand(1, 1, N_O, 3), torch.rand(1, N_S, 3), r"object_points: expected shape \(B, N, 3\)"),
    ],
)
def test_bad_input_names_the_argument(obj, scene, message):
    with pytest.raises(PointCloudError, match=message):
        tiny_policy().sample_goals(obj, scene, 1)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"sampler": "DDIM"}, r"sampler: must be one of \['ddim', 'ddpm'\], got 'DDIM'"),
        ({"num_inference_steps": 0}, "num_inference_steps: must divide num_train_timesteps=100"),
        ({"num_inference_steps": 7}, "got 7"),
        ({"num_samples": 0}, "num_samples: must be a positive integer"),
        ({"gmm_frames": "mode"}, r"gmm_frames: must be one of \['components', 'modes'\], got 'mode'"),
        ({"frame_temperature": -1.0}, r"frame_temperature: must be a finite number >= 0, got -1.0"),
    ],
)
def test_bad_sampling_options_name_the_option(options, message):
    obj, scene = clouds(1)
    options = {"num_samples": 1, **options}
    with pytest.raises(ValueError, match=message):
        tiny_policy().sample_goals(obj, scene, **options)


def test_inputs_in_the_wrong_units_are_flagged_with_the_likely_cause():
    policy = tiny_policy()  # trained scale: radius 3 model units at point_scale 20, i.e. 0.15 m objects
    obj, scene = clouds(1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # metres: no warning
        policy.sample_goals(obj, scene, 1)
    with pytest.warns(UserWarning, match=r"object_points: the object's radius is .* these look like millimetres"):
        policy.sample_goals(obj * 1000, scene * 1000, 1)
    policy.train().forward({OBJECT_KEY: obj * 50, SCENE_KEY: scene * 50, ACTION_KEY: obj * 50})
    with pytest.warns(UserWarning, match="observation.pointcloud.object: .* check the units"):
        policy.update()  # a training step's checks are read back at its end, as lerobot-train calls it


def test_training_batch_with_mismatched_goal_is_rejected():
    policy = tiny_policy().train()
    obj, scene = clouds()
    with pytest.raises(PointCloudError, match="observation.pointcloud.object and action: shapes"):
        policy.forward({OBJECT_KEY: obj, SCENE_KEY: scene, ACTION_KEY: obj[:, :-1]})
    with pytest.raises(PointCloudError, match="action: missing"):
        policy.forward({OBJECT_KEY: obj, SCENE_KEY: scene})


@pytest.mark.parametrize("stage", ["global_stage", "local_stage.denoiser"])
def test_each_dit_block_gets_the_modulation_and_context_its_own_layers_give(stage):
    """The DiT projects the condition and the normalised context for all its blocks in one product each; with a
    shipped predictor's trained weights every block must receive exactly what its own layers would compute."""
    dit = load_goal_predictor("mug_easyrack").model.get_submodule(stage).backbone
    dim = dit.norm_context.normalized_shape[0]
    g = torch.Generator().manual_seed(0)
    tokens, context, condition = (torch.randn(*shape, generator=g) for shape in ((2, 5, dim), (2, 7, dim), (2, dim)))
    expected = tokens
    for block in dit.blocks:
        keys_values = block.cross_attention.key_value(dit.norm_context(context))
        expected = block(expected, keys_values, block.modulation_of(condition))
    with torch.no_grad():
        torch.testing.assert_close(dit(tokens, context, condition), expected, rtol=1e-5, atol=1e-5)
        given = dit(tokens, context, modulations=dit.modulations_of(condition))  # as a sampling loop hands them
        torch.testing.assert_close(given, expected, rtol=1e-5, atol=1e-5)
    assert len(dit.blocks) > 1 and not torch.allclose(expected, tokens)  # trained blocks that act


def test_the_sampling_loop_conditions_every_step_as_its_timestep_alone_would():
    """The loop computes the modulations of all its timesteps at once and hands each step its row: with a shipped
    predictor's weights, each row is what that step's timestep alone gives, for the DiT and both output heads."""
    denoiser = load_goal_predictor("mug_easyrack").model.local_stage.denoiser
    timesteps = torch.tensor([90, 60, 30, 0])
    with torch.no_grad():
        together = denoiser.conditioning(timesteps)
        for index, t in enumerate(timesteps):
            alone, row = denoiser.conditioning(torch.full((3,), int(t))), together.step(index, 3)
            torch.testing.assert_close(row.backbone, alone.backbone, rtol=1e-5, atol=1e-6)
            for head in ("point_head", "frame_head"):
                for given, own in zip(getattr(row, head), getattr(alone, head), strict=True):
                    torch.testing.assert_close(given, own, rtol=1e-5, atol=1e-6)
    assert not torch.allclose(together.backbone[0], together.backbone[-1])  # the timestep matters


def test_gmm_frames_at_modes_climb_to_the_peak_of_the_slot_they_were_drawn_at():
    """gmm_frames="modes": frames drawn at any of the components scattered over one slot all end at the peak of
    the mixture's density there, each at a density no lower than where it started; components of another slot
    go to that slot's peak."""
    gmm = tiny_policy(gmm_frames="modes").model.global_stage
    sigma = gmm.variance**0.5
    g = torch.Generator().manual_seed(0)
    slots = torch.tensor([[0.0, 0.0, 0.0], [6 * sigma, 0.0, 0.0]])
    means = (slots.repeat_interleave(20, 0) + 0.3 * sigma * torch.randn(40, 3, generator=g)).unsqueeze(0)
    weights = torch.softmax(torch.randn(1, 40, generator=g), -1)

    def density(points: torch.Tensor) -> torch.Tensor:
        d2 = (points.unsqueeze(2) - means.unsqueeze(1)).square().sum(-1)
        return (weights.unsqueeze(1) * torch.exp(-0.5 * d2 / gmm.variance)).sum(-1)

    peaks = gmm.climb_to_modes(means, weights, means)
    assert (density(peaks) >= density(means) * (1 - 1e-6)).all()
    for slot in (peaks[0, :20], peaks[0, 20:]):
        assert (slot - slot.mean(0)).norm(dim=-1).max() < 1e-3 * sigma  # one point per slot, from 0.3 sigma apart
    assert (peaks[0, :20].mean(0) - peaks[0, 20:].mean(0)).norm() > 5 * sigma  # the slots are not merged
    assert not torch.allclose(peaks, means)


def test_a_policy_samples_its_frames_as_configured_or_as_asked():
    """Each way of drawing the frames gives goals of its own from the same random draws, the config's way unless
    a call asks for the other."""
    obj, scene = clouds(1)
    goals = {
        (frames, asked): tiny_policy(gmm_frames=frames).sample_goals(
            obj, scene, 4, generator=torch.Generator().manual_seed(0), gmm_frames=asked
        )
        for frames in ("components", "modes")
        for asked in (None, "components", "modes")
    }
    torch.testing.assert_close(goals["components", None], goals["modes", "components"])
    torch.testing.assert_close(goals["modes", None], goals["components", "modes"])
    assert not torch.allclose(goals["components", None], goals["modes", None])


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (dict(frame_temperature=-0.5), r"frame_temperature: must be a finite number >= 0, got -0.5"),
        (dict(frame_temperature=float("nan")), r"frame_temperature: must be a finite number >= 0, got nan"),
        (dict(frame_temperature="cold"), r"frame_temperature: must be a number >= 0, got 'cold'"),
        (dict(frame_temperature=0.5, disentangled=False), "frame_temperature: needs disentangled=true"),
    ],
)
def test_a_frame_temperature_it_cannot_serve_is_refused_by_name(overrides, message):
    with pytest.raises(ValueError, match=message):
        TaxDPDConfig.for_point_clouds(N_O, N_S, **overrides)


def test_a_cold_frame_start_gathers_the_samples_at_their_placement_frame():
    """frame_temperature=0 starts every sample's frame at its placement frame: with the shipped book
    predictor, the centroids of 16 goals sampled at one frame (a held-out scene's true one) scatter several
    times less than with the published full-scale start; a call's `frame_temperature` overrides the config's."""
    policy = load_goal_predictor("book_shelf")
    task = get_task("book_shelf")

    def sample(trial, **temperature) -> torch.Tensor:
        obj, scene = torch.from_numpy(trial.object_points)[None], torch.from_numpy(trial.scene_points)[None]
        frame = torch.from_numpy(trial.goal_points().mean(0))[None]
        generator = torch.Generator().manual_seed(0)
        return policy.sample_goals(obj, scene, 16, generator=generator, placement_frames=frame, **temperature)

    for seed in (2000, 2001):
        trial = make_trial(task, seed, "test")
        spread = {}
        for temperature in (1.0, 0.0):
            centroids = sample(trial, frame_temperature=temperature)[0].mean(1)
            spread[temperature] = float((centroids - centroids.mean(0)).norm(dim=-1).median()) * 1000
        print(f"scene {seed}: median centroid spread {spread[1.0]:.1f} mm at temperature 1, {spread[0.0]:.1f} at 0")
        assert spread[0.0] < 0.25 * spread[1.0]
    assert policy.config.frame_temperature == 0.0  # as shipped
    torch.testing.assert_close(sample(trial), sample(trial, frame_temperature=0.0))
    policy.config.frame_temperature = 1.0
    torch.testing.assert_close(sample(trial), sample(trial, frame_temperature=1.0))


def test_a_dit_block_computes_adaln_zero_as_written():
    """The fused multiply-adds of a block (`addcmul`, the scales' 1 added once) compute the adaLN-Zero block
    written out op by op, with a shipped predictor's trained weights."""
    block = load_goal_predictor("mug_easyrack").model.local_stage.denoiser.backbone.blocks[0]
    dim = block.norm_self.normalized_shape[0]
    g = torch.Generator().manual_seed(1)
    x, context, condition = (torch.randn(*shape, generator=g) for shape in ((2, 5, dim), (2, 7, dim), (2, dim)))
    keys_values = block.cross_attention.key_value(context)
    shift1, scale1, gate1, shift2, scale2, gate2, shift3, scale3, gate3 = (
        m.unsqueeze(1) for m in block.modulation(condition).chunk(9, dim=-1)
    )
    with torch.no_grad():
        h = block.norm_self(x) * (1 + scale1) + shift1
        expected = x + gate1 * block.self_attention(h, h)
        h = block.norm_cross(expected) * (1 + scale2) + shift2
        expected = expected + gate2 * block.cross_attention.attend(h, keys_values)
        expected = expected + gate3 * block.mlp(block.norm_mlp(expected) * (1 + scale3) + shift3)
        torch.testing.assert_close(block(x, keys_values, block.modulation_of(condition)), expected)
    assert not torch.allclose(expected, x)


def test_amp_on_a_cpu_whose_bf16_is_slow_warns_with_the_measured_ratio():
    """Whether bf16 pays is measured on this CPU: a policy built with use_amp to run on it warns exactly when
    its bf16 products are slower than its fp32 ones, and a policy without use_amp never does."""
    speedup = cpu_bf16_speedup()
    print(f"\nbf16 matrix products on this CPU: {speedup:.2f}x the speed of fp32 ones")
    for use_amp, expected in ((True, speedup < 1.0), (False, False)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            tiny_policy(use_amp=use_amp)
        assert any("use_amp=true" in str(w.message) for w in caught) == expected, use_amp


def test_loss_reports_each_part_and_reaches_every_parameter():
    policy = tiny_policy().train()
    obj, scene = clouds(4)
    loss, parts = policy.forward({OBJECT_KEY: obj, SCENE_KEY: scene, ACTION_KEY: obj + 0.2})
    assert set(parts) == {"loss_gmm", "loss_local", "loss_frame", "loss_shape"}
    loss.backward()
    assert all(p.grad is not None for p in policy.parameters())
    policy.update()  # the end of the step: the parts become the floats a logger takes
    assert all(type(value) is float and math.isfinite(value) for value in parts.values())
    assert parts["loss_local"] == pytest.approx(loss.item() - parts["loss_gmm"], rel=1e-5)


@pytest.mark.parametrize("key", [OBJECT_KEY, SCENE_KEY, ACTION_KEY])
def test_a_training_batch_with_nan_stops_training_naming_the_field(key):
    policy = tiny_policy().train()
    obj, scene = clouds(4)
    batch = {OBJECT_KEY: obj.clone(), SCENE_KEY: scene.clone(), ACTION_KEY: obj + 0.2}
    batch[key][1, 2, 0] = float("nan")
    policy.forward(batch)  # queued without waiting for the device
    with pytest.raises(PointCloudError, match=rf"{key}: contains 1 NaN"):
        policy.update()
    clean = {OBJECT_KEY: obj, SCENE_KEY: scene, ACTION_KEY: obj + 0.2}
    policy.forward(batch)
    with pytest.raises(PointCloudError, match=rf"{key}: contains 1 NaN"):  # without update(): the next call
        policy.forward(clean)


def test_point_clouds_are_never_normalised_per_axis():
    with pytest.raises(ValueError, match="must be IDENTITY"):
        TaxDPDConfig(normalization_mapping={"STATE": "MEAN_STD", "ACTION": "IDENTITY"})


def test_processor_batches_a_single_sample_and_unpacks_env_clouds():
    policy = tiny_policy()
    preprocessor, postprocessor = make_taxdpd_pre_post_processors(policy.config)
    obj, scene = clouds(1)
    single = preprocessor({OBJECT_KEY: obj[0], SCENE_KEY: scene[0]})
    assert single[OBJECT_KEY].shape == (1, N_O, 3)
    goal = policy.select_action(single)
    assert goal.shape == (1, N_O, 3)
    action = postprocessor(goal)  # LeRobot's (batch, action_dim) layout, row by row
    assert action.shape == (1, N_O * 3) and torch.equal(action.reshape(1, N_O, 3), goal)
    packed = preprocessor({"observation.environment_state": torch.cat([obj[0], scene[0]])})
    assert torch.equal(packed[OBJECT_KEY], obj) and torch.equal(packed[SCENE_KEY], scene)


def test_save_and_load_round_trip_keeps_weights_scale_metrics_and_card(tmp_path):
    policy = tiny_policy()
    policy.metrics = {
        "task": "insert_ssd",
        "success": {"success_rate": 0.93, "ci95_low": 0.86, "ci95_high": 0.97, "trials": 100},
        "translation_error_mm": {"median": 1.25, "mean": 1.5, "p90": 2.5},
    }
    policy.save_pretrained(tmp_path)
    loaded = TaxDPDPolicy.from_pretrained(tmp_path)
    assert loaded.config.point_scale == 20.0 and loaded.metrics == policy.metrics
    obj, scene = clouds()
    expected = policy.sample_goals(obj, scene, 2, generator=torch.Generator().manual_seed(1))
    assert torch.equal(loaded.sample_goals(obj, scene, 2, generator=torch.Generator().manual_seed(1)), expected)
    card = (tmp_path / "README.md").read_text()
    assert "| `use_gmm` | `True` |" in card and "library_name: lerobot" in card
    assert "# TAX-DPD goal predictor for `insert_ssd`" in card and 'load_goal_predictor("insert_ssd")' in card
    assert "success 93% (95% CI 86%-97%, 100 trials)" in card
    pushed_card = str(loaded.generate_model_card("me/slots", "taxdpd", None, ["extra"]))
    assert "datasets:" in pushed_card and "me/slots" in pushed_card and "translation_error_mm" in pushed_card


def test_with_ema_goals_come_from_the_averaged_weights_which_save_resume_and_ship(tmp_path):
    policy = tiny_policy(use_ema=True)
    trained = {id(p) for p in policy.get_optim_params()}
    assert trained == {id(p) for p in policy.model.parameters()}, "the average is outside the optimiser"
    with torch.no_grad():
        for p in policy.model.parameters():
            p.add_(0.05)
    policy.update()  # first step: decay 0, the average takes the trained weights
    with torch.no_grad():
        for p in policy.model.parameters():
            p.add_(0.05)
    for _ in range(3):
        policy.update()
    obj, scene = clouds()
    seeded = dict(generator=torch.Generator().manual_seed(2))
    goals = policy.sample_goals(obj, scene, 2, **seeded)
    raw = tiny_policy()
    raw.model.load_state_dict(policy.model.state_dict())
    assert not torch.allclose(raw.sample_goals(obj, scene, 2, generator=torch.Generator().manual_seed(2)), goals)
    plain = policy.without_ema()
    assert not plain.config.use_ema and not hasattr(plain, "ema_model")
    assert torch.equal(plain.sample_goals(obj, scene, 2, generator=torch.Generator().manual_seed(2)), goals)
    policy.save_pretrained(tmp_path / "checkpoint")  # lerobot-train's checkpoint: the average resumes with it
    resumed = TaxDPDPolicy.from_pretrained(tmp_path / "checkpoint")
    assert int(resumed.ema_step) == 4
    assert torch.equal(resumed.sample_goals(obj, scene, 2, generator=torch.Generator().manual_seed(2)), goals)
    save_shipped(policy, tmp_path / "checkpoint", tmp_path / "shipped")
    shipped = TaxDPDPolicy.from_pretrained(tmp_path / "shipped")
    assert not shipped.config.use_ema and not any(k.startswith("ema") for k in shipped.state_dict())
    fp16 = shipped.sample_goals(obj, scene, 2, generator=torch.Generator().manual_seed(2))
    assert torch.allclose(fp16, goals, atol=1e-2), "what ships samples as the averaged weights do (to fp16)"


def test_hub_id_loads_offline_from_the_huggingface_cache(tmp_path, hf_home):
    policy = tiny_policy()
    policy.metrics = {"rmse_mm": 4.0}
    policy.save_pretrained(tmp_path / "model")
    install_in_hub_cache(hf_home, "taxdpd-tests/tiny", tmp_path / "model")
    config = PreTrainedConfig.from_pretrained("taxdpd-tests/tiny")
    assert isinstance(config, TaxDPDConfig)
    loaded = TaxDPDPolicy.from_pretrained("taxdpd-tests/tiny")
    assert loaded.metrics == {"rmse_mm": 4.0}
    for name, tensor in policy.state_dict().items():
        assert torch.equal(tensor, loaded.state_dict()[name]), name
    with pytest.raises(Exception, match="offline|cannot find|not found|couldn't|Cannot find"):
        TaxDPDPolicy.from_pretrained("taxdpd-tests/not-cached")


def test_saved_processors_accept_lerobots_override_keys(tmp_path):
    policy = tiny_policy()
    preprocessor, postprocessor = make_taxdpd_pre_post_processors(policy.config)
    preprocessor.save_pretrained(tmp_path)
    postprocessor.save_pretrained(tmp_path)
    overrides = {
        "device_processor": {"device": "cpu"},
        "rename_observations_processor": {"rename_map": {}},
        "normalizer_processor": {"stats": None},
    }
    reloaded = PolicyProcessorPipeline.from_pretrained(
        tmp_path, config_filename="policy_preprocessor.json", overrides=overrides
    )
    PolicyProcessorPipeline.from_pretrained(
        tmp_path, config_filename="policy_postprocessor.json", overrides={"unnormalizer_processor": {"stats": None}}
    )
    obj, scene = clouds(1)
    assert reloaded({OBJECT_KEY: obj[0], SCENE_KEY: scene[0]})[OBJECT_KEY].shape == (1, N_O, 3)
    saved = json.loads((tmp_path / "policy_preprocessor.json").read_text())
    assert "taxdpd_point_cloud_batch" in [step.get("registry_name") for step in saved["steps"]]


@pytest.mark.parametrize(
    "switches",
    [
        {"disentangled": False},
        {"encoder": "mlp"},
        {"use_gmm": False},
        {"use_reconstruction_embedding": False},
        {"use_rotation_noise": False},
        {"use_deformation_embedding": False},
        {"local_diffusion": "se3"},
        {"frame_from_points": True},
        {
            "use_gmm": False,
            "disentangled": False,
            "use_reconstruction_embedding": False,
            "use_deformation_embedding": False,
        },
    ],
)
def test_every_ablation_trains_and_samples(switches):
    policy = tiny_policy(**switches).train()
    obj, scene = clouds(3)
    loss, _ = policy.forward({OBJECT_KEY: obj, SCENE_KEY: scene, ACTION_KEY: obj + 0.3})
    loss.backward()
    assert all(p.grad is not None for p in policy.parameters())  # DDP-safe: no parameter sits idle
    goals = policy.eval().sample_goals(obj, scene, 2)
    assert goals.shape == (3, 2, N_O, 3) and bool(torch.isfinite(goals).all())
    if not switches.get("use_gmm", True):
        with pytest.raises(RuntimeError, match="without the Dense GMM"):
            policy.placement_distribution(obj, scene)


def test_se3_variant_outputs_rigid_goals():
    policy = tiny_policy(local_diffusion="se3")
    obj, scene = clouds(2)
    goals = policy.sample_goals(obj, scene, 2)
    source = obj.unsqueeze(1).double()
    distances = lambda x: torch.cdist(x, x)  # noqa: E731
    assert torch.allclose(distances(goals.double()), distances(source.expand_as(goals)), atol=1e-4)


def test_numpy_inputs_are_accepted():
    obj, scene = clouds(1)
    goals = tiny_policy().sample_goals(obj.numpy().astype(np.float64), scene.numpy(), 1)
    assert isinstance(goals, torch.Tensor) and goals.shape == (1, 1, N_O, 3)
