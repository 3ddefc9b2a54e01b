"""`gc_dp3` pieces: config checks, how clouds are normalised, action chunking, EMA."""

from __future__ import annotations

import pytest
import torch
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
from lerobot.policies.diffusion.modeling_diffusion import DiffusionConditionalUnet1d
from lerobot.processor import PolicyProcessorPipeline

from lerobot_taxdpd import GcDp3Config, make_gc_dp3_pre_post_processors
from lerobot_taxdpd.data.schema import ACTION_KEY, GOAL_CLOUD_KEY, OBJECT_KEY, SCENE_KEY, STATE_KEY
from lerobot_taxdpd.policies.gc_dp3.modeling_gc_dp3 import GcDp3Policy

CLOUDS = (OBJECT_KEY, SCENE_KEY, GOAL_CLOUD_KEY)
SMALL = {
    "down_dims": (16, 32),
    "point_encoder_dims": (16, 16),
    "point_feature_dim": 16,
    "state_encoder_dims": (16, 16),
    "diffusion_step_embed_dim": 16,
    "num_inference_steps": 3,
    "device": "cpu",
    # Policies built here have no dataset, from which the default ("isotropic") derives its frame: that mode
    # is tested on its own below and through lerobot-train (test_gc_dp3_train.py).
    "cloud_normalization": "none",
}


def features(points: int = 24) -> tuple[dict, dict]:
    inputs = {key: PolicyFeature(FeatureType.STATE, (points, 3)) for key in CLOUDS}
    inputs[STATE_KEY] = PolicyFeature(FeatureType.STATE, (12,))
    return inputs, {ACTION_KEY: PolicyFeature(FeatureType.ACTION, (6,))}


def make_config(**overrides) -> GcDp3Config:
    inputs, outputs = features()
    return GcDp3Config(input_features=inputs, output_features=outputs, **{**SMALL, **overrides})


def stats() -> dict[str, dict[str, torch.Tensor]]:
    cloud = {"min": torch.full((3,), -5.0), "max": torch.full((3,), 5.0), "mean": torch.zeros(3), "std": torch.ones(3)}
    return {
        **{key: cloud for key in CLOUDS},
        STATE_KEY: {"min": -torch.ones(12) * 2, "max": torch.ones(12) * 2},
        ACTION_KEY: {"min": -torch.ones(6) * 0.1, "max": torch.ones(6) * 0.1},
    }


def observation(points: int = 24, batch: tuple[int, ...] = ()) -> dict[str, torch.Tensor]:
    generator = torch.Generator().manual_seed(0)
    obs = {key: torch.randn(*batch, points, 3, generator=generator) for key in CLOUDS}
    obs[STATE_KEY] = torch.randn(*batch, 12, generator=generator)
    return obs


def test_defaults_follow_dp3_cloth_variant():
    config = GcDp3Config()
    assert (config.horizon, config.n_obs_steps, config.n_action_steps) == (4, 2, 4)
    assert config.prediction_type == "sample" and config.num_inference_steps == 10
    assert config.optimizer_betas == (0.95, 0.999) and config.optimizer_weight_decay == 1e-6
    assert config.observation_delta_indices == [-1, 0] and config.action_delta_indices == [0, 1, 2, 3]
    assert config.cloud_keys == CLOUDS


def test_the_denoiser_is_lerobots_unet_and_film_follows_the_flag():
    """The action denoiser is LeRobot's diffusion-policy U-Net; only the point encoder is gc_dp3's own."""
    policy = GcDp3Policy(make_config())
    assert isinstance(policy.model.unet, DiffusionConditionalUnet1d)
    shift_only = GcDp3Policy(make_config(use_film_scale_modulation=False))
    count = lambda module: sum(p.numel() for p in module.parameters())  # noqa: E731
    assert count(shift_only.model.unet) < count(policy.model.unet)  # FiLM predicts shifts only


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"n_action_steps": 5}, "n_action_steps"),
        ({"horizon": 6, "down_dims": (16, 32, 64)}, "divisible"),
        ({"down_dims": (12, 24)}, "n_groups"),
        ({"prediction_type": "v_prediction"}, "prediction_type"),
        ({"num_inference_steps": 0}, "num_inference_steps"),
        ({"points_per_cloud": 0}, "points_per_cloud"),
        ({"cloud_normalization": "per_point"}, "cloud_normalization"),
        ({"cloud_scale": 0.0}, "cloud_scale"),
        (
            {
                "normalization_mapping": {
                    "STATE": NormalizationMode.MIN_MAX,
                    "ENV": NormalizationMode.MIN_MAX,
                    "ACTION": NormalizationMode.MIN_MAX,
                }
            },
            "ENV",
        ),
    ],
)
def test_config_rejects_bad_values(overrides, message):
    with pytest.raises(ValueError, match=message):
        make_config(**overrides)


def test_policy_names_the_missing_goal_feature():
    inputs, outputs = features()
    del inputs[GOAL_CLOUD_KEY]
    config = GcDp3Config(input_features=inputs, output_features=outputs, **SMALL)
    with pytest.raises(ValueError, match=GOAL_CLOUD_KEY):
        GcDp3Policy(config)


def test_processors_normalise_state_and_action_but_never_clouds():
    config = make_config()
    preprocessor, postprocessor = make_gc_dp3_pre_post_processors(config, dataset_stats=stats())
    raw = observation()
    processed = preprocessor({**raw, ACTION_KEY: torch.full((6,), 0.05)})
    for key in CLOUDS:
        assert processed[key].shape == (1, 24, 3), "a single observation gets a batch dimension"
        torch.testing.assert_close(processed[key][0], raw[key])
    torch.testing.assert_close(processed[STATE_KEY][0], raw[STATE_KEY] / 2.0)
    torch.testing.assert_close(processed[ACTION_KEY][0], torch.full((6,), 0.5))
    torch.testing.assert_close(postprocessor(torch.full((1, 6), -0.5)), torch.full((1, 6), -0.05))
    assert config.normalization_mapping["STATE"] is NormalizationMode.MIN_MAX


@pytest.mark.parametrize("mode", ["none", "isotropic", "per_axis"])
def test_clouds_come_out_the_same_when_lerobot_rebuilds_the_normaliser(tmp_path, mode):
    """`lerobot-train --resume=true` and `--policy.path` reload the saved preprocessor with the normaliser
    rebuilt from all of the policy's input features (lerobot_train.py): clouds must come out as they did in
    the first run, untouched unless `cloud_normalization="per_axis"` (then min-max normalised)."""
    config = make_config(cloud_normalization=mode)
    GcDp3Policy(config, dataset_stats=stats())  # types the clouds, as every policy construction does
    preprocessor, _ = make_gc_dp3_pre_post_processors(config, dataset_stats=stats())
    preprocessor.save_pretrained(tmp_path)
    overrides = {
        "normalizer_processor": {
            "stats": stats(),
            "features": {**config.input_features, **config.output_features},
            "norm_map": config.normalization_mapping,
        }
    }
    rebuilt = PolicyProcessorPipeline.from_pretrained(
        tmp_path, config_filename="policy_preprocessor.json", overrides=overrides
    )
    raw = observation()
    first, resumed = preprocessor(dict(raw)), rebuilt(dict(raw))
    for key in CLOUDS:
        expected = raw[key] / 5.0 if mode == "per_axis" else raw[key]  # stats: every axis in [-5, 5]
        torch.testing.assert_close(first[key][0], expected)
        torch.testing.assert_close(resumed[key][0], expected)
    torch.testing.assert_close(resumed[STATE_KEY][0], raw[STATE_KEY] / 2.0)


def test_isotropic_clouds_share_one_origin_and_one_scale_kept_in_the_checkpoint(tmp_path):
    """The "isotropic" mode maps the box around every cloud of the dataset into [-1, 1] along its longest side with
    one shift and one scale for all clouds, so the offsets between cloth, hanger and goal only shrink; the
    checkpoint keeps that frame and does not re-derive it."""
    data_stats = stats()
    data_stats[SCENE_KEY] = {"min": torch.tensor([-1.0, -2.0, 0.0]), "max": torch.tensor([3.0, 2.0, 9.0])}
    policy = GcDp3Policy(make_config(cloud_normalization="isotropic"), dataset_stats=data_stats)
    assert policy.config.cloud_center == [0.0, 0.0, 2.0] and policy.config.cloud_scale == 7.0  # box [-5, 5]^2 x [-5, 9]
    batch = observation(batch=(2,))
    cloud = policy.model.segmented_cloud(batch)[..., :3]
    torch.testing.assert_close(cloud, torch.cat([(batch[k] - torch.tensor([0.0, 0.0, 2.0])) / 7.0 for k in CLOUDS], 1))
    policy.save_pretrained(tmp_path)
    assert "model.cloud_center" not in policy.state_dict(), "config.json carries the frame, not the weights"
    loaded = GcDp3Policy.from_pretrained(tmp_path)
    assert (loaded.config.cloud_center, loaded.config.cloud_scale) == ([0.0, 0.0, 2.0], 7.0)
    torch.testing.assert_close(loaded.model.segmented_cloud(batch), policy.model.segmented_cloud(batch))
    with pytest.raises(ValueError, match=GOAL_CLOUD_KEY):
        GcDp3Policy(make_config(cloud_normalization="isotropic"), dataset_stats={OBJECT_KEY: data_stats[OBJECT_KEY]})


def test_single_observation_runs_end_to_end_and_chunks_actions(monkeypatch):
    config = make_config()
    policy = GcDp3Policy(config).eval()
    preprocessor, postprocessor = make_gc_dp3_pre_post_processors(config, dataset_stats=stats())
    calls = []
    generate = policy.model.generate_actions
    monkeypatch.setattr(policy.model, "generate_actions", lambda *a, **k: calls.append(1) or generate(*a, **k))
    actions = [postprocessor(policy.select_action(preprocessor(observation()))) for _ in range(9)]
    assert all(a.shape == (1, 6) and bool(torch.isfinite(a).all()) for a in actions)
    assert all(a.abs().max() <= 0.1 + 1e-6 for a in actions), "clipped samples stay inside the data range"
    assert len(calls) == 3, "one chunk of n_action_steps=4 actions per denoising run"


def test_training_batch_gives_a_finite_loss_with_gradients_everywhere():
    policy = GcDp3Policy(make_config(points_per_cloud=8))
    batch = {
        key: value.unsqueeze(1).repeat(1, 2, *[1] * (value.dim() - 1)) for key, value in observation(batch=(5,)).items()
    }
    batch[ACTION_KEY] = torch.rand(5, 4, 6) * 2 - 1
    batch["action_is_pad"] = torch.zeros(5, 4, dtype=torch.bool)
    loss, _ = policy.forward(batch)
    loss.backward()
    assert torch.isfinite(loss)
    assert all(p.grad is not None for p in policy.get_optim_params()), "DDP needs every parameter used"


def test_ema_tracks_the_trained_weights():
    policy = GcDp3Policy(make_config(use_ema=True))
    assert not any(p.requires_grad for p in policy.ema_model.parameters())
    with torch.no_grad():
        for p in policy.model.parameters():
            p.add_(1.0)
    policy.update()  # first step: decay 0, the average jumps to the weights
    torch.testing.assert_close(list(policy.ema_model.parameters())[0], list(policy.model.parameters())[0])
    before = [p.clone() for p in policy.ema_model.parameters()]
    with torch.no_grad():
        for p in policy.model.parameters():
            p.add_(1.0)
    for _ in range(5):
        policy.update()
    moved = [(a - b).abs().mean().item() for a, b in zip(policy.ema_model.parameters(), before, strict=True)]
    assert all(0.0 < m < 1.0 for m in moved), "the average moves part of the way"
    assert int(policy.ema_step) == 6 and "ema_step" in policy.state_dict()


def test_observation_with_nan_is_refused():
    policy = GcDp3Policy(make_config()).eval()
    obs = {key: value.unsqueeze(0) for key, value in observation().items()}
    obs[GOAL_CLOUD_KEY][0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match=GOAL_CLOUD_KEY):
        policy.select_action(obs)


def test_a_saved_checkpoint_gets_its_own_model_card(tmp_path):
    GcDp3Policy(make_config()).save_pretrained(tmp_path)
    card = (tmp_path / "README.md").read_text()
    assert "# gc_dp3: goal-conditioned 3D Diffusion Policy" in card and "not recognized" not in card
    assert "load_gc_dp3(" in card and "pip install lerobot_policy_taxdpd" in card
    assert "| `down_dims` | `(16, 32)` |" in card
