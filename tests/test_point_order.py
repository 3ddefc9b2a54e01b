"""Datasets record whether their clouds are in farthest-point order; a training step on such a dataset takes its
encoder layouts as prefixes (no FPS launches) and computes exactly the loss that running FPS gives."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.policies.factory import make_policy

from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy
from lerobot_taxdpd.apps.synthetic import make_slot_scene
from lerobot_taxdpd.data.dataset_writer import DatasetCardInfo, DatasetWriter
from lerobot_taxdpd.data.point_order import POINT_ORDER_FILE, is_farthest_point_ordered, read_point_order
from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY, goal_prediction_features, placement_frame
from lerobot_taxdpd.maths.geometry import device_code_paths, farthest_point_indices, is_farthest_point_prefix
from lerobot_taxdpd.policies.taxdpd import modeling_taxdpd
from lerobot_taxdpd.reports.launches import LaunchCounter

NUM_OBJECT, NUM_SCENE = 64, 128
CARD = DatasetCardInfo(source="unit test", source_license="apache-2.0", command="pytest")


def fps_reduced(points: np.ndarray, count: int) -> np.ndarray:
    """`count` points of a larger cloud by FPS, in selection order (as the tasks record their renders)."""
    return points[farthest_point_indices(points, count)]


def slot_frames(rng: np.random.Generator, order_scene: bool = True) -> list[dict]:
    frames = []
    for _ in range(2):
        scene = make_slot_scene(rng, 2 * NUM_OBJECT, 2 * NUM_SCENE)
        keep = farthest_point_indices(scene.object_points, NUM_OBJECT)
        scene_points = fps_reduced(scene.scene_points, NUM_SCENE)
        scene_points = scene_points if order_scene else rng.permutation(scene_points)
        frames.append(
            placement_frame(scene.object_points[keep], scene_points, scene.goal_points[keep], None, source="test")
        )
    return frames


def write(root, order_scene: bool = True) -> None:
    rng = np.random.default_rng(0)
    features = goal_prediction_features(NUM_OBJECT, NUM_SCENE, with_transform=False)
    with DatasetWriter("local/order", root, features, fps=10, card=CARD) as writer:
        for _ in range(3):
            writer.add_episode(slot_frames(rng, order_scene), "place it")


def test_the_order_check_accepts_fps_orders_ties_included_and_rejects_others():
    rng = np.random.default_rng(1)
    cloud = fps_reduced(rng.normal(size=(1200, 3)), 300)
    assert is_farthest_point_ordered(cloud)
    assert not is_farthest_point_ordered(cloud[rng.permutation(300)])
    assert not is_farthest_point_ordered(cloud[::-1])
    # A render that comes at exactly the recorded size is put in FPS order too, not kept as it came.
    whole = rng.normal(size=(300, 3))
    assert is_farthest_point_ordered(fps_reduced(whole, 300)) and not is_farthest_point_ordered(whole)
    # A cube's corners: after the first two, every point ties with others; any order among ties is FPS's.
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    first, opposite = corners[0], corners[7]
    rest = corners[1:7][[3, 0, 5, 1, 4, 2]]  # the six others, all at distance 1 or sqrt(2) from both
    assert is_farthest_point_ordered(np.vstack([first, opposite, rest]))
    assert is_farthest_point_ordered(np.vstack([cloud, cloud[:4]]))  # duplicates come last, at distance 0
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        is_farthest_point_ordered(cloud[:, :2])


def test_the_writer_records_which_fields_are_in_fps_order(tmp_path):
    write(tmp_path / "ordered")
    assert read_point_order(tmp_path / "ordered") == {OBJECT_KEY: True, SCENE_KEY: True}
    write(tmp_path / "shuffled", order_scene=False)
    assert read_point_order(tmp_path / "shuffled") == {OBJECT_KEY: True, SCENE_KEY: False}
    assert read_point_order(tmp_path) == {}  # no record: treated as unordered
    (tmp_path / "ordered" / POINT_ORDER_FILE).write_text('{"farthest_point_ordered": {"x": "yes"}}')
    with pytest.raises(ValueError, match="taxdpd_point_order.json.*farthest_point_ordered"):
        read_point_order(tmp_path / "ordered")


def step_loss_and_launches(policy: TaxDPDPolicy, batch: dict) -> tuple[float, LaunchCounter]:
    torch.manual_seed(3)
    counter = LaunchCounter()
    with device_code_paths(), counter:
        loss, _ = policy.forward(batch)
    policy.update()
    return float(loss.detach()), counter


def test_a_step_on_fps_ordered_data_skips_fps_and_keeps_its_loss(tmp_path):
    write(tmp_path / "ordered")
    meta = LeRobotDatasetMetadata("local/order", root=tmp_path / "ordered")
    fields = dict(hidden_dim=32, num_blocks=1, num_object_points=NUM_OBJECT, num_scene_points=NUM_SCENE)
    torch.manual_seed(0)  # built as lerobot-train builds it, from the dataset's metadata
    ordered = make_policy(TaxDPDConfig(device="cpu", **fields), ds_meta=meta).train()
    torch.manual_seed(0)
    config = TaxDPDConfig.for_point_clouds(device="cpu", point_scale=ordered.config.point_scale, **fields)
    unknown = TaxDPDPolicy(config).train()
    assert ordered.training_clouds_fps_ordered == (True, True)
    assert unknown.training_clouds_fps_ordered == (False, False)

    frames = slot_frames(np.random.default_rng(5)) + slot_frames(np.random.default_rng(6))
    batch = {key: torch.from_numpy(np.stack([f[key] for f in frames])) for key in (OBJECT_KEY, SCENE_KEY, ACTION_KEY)}
    loss_ordered, launches_ordered = step_loss_and_launches(ordered, batch)
    loss_unknown, launches_unknown = step_loss_and_launches(unknown, batch)
    assert loss_ordered == pytest.approx(loss_unknown, rel=1e-6)
    fps_loop = launches_unknown.ops["other"]["argmax"]
    print(f"\nforward: {launches_unknown.total_ops()} ops (FPS in the step) -> {launches_ordered.total_ops()}")
    assert fps_loop >= NUM_OBJECT // 4  # level-1 centres of both clouds, one loop iteration each
    assert launches_ordered.ops["other"].get("argmax", 0) == 0
    assert launches_unknown.total_ops() - launches_ordered.total_ops() >= 2 * fps_loop


def test_the_policys_prefix_check_agrees_with_the_writers_order_check():
    """`is_farthest_point_prefix` (parallel torch ops, what sampling uses) against the writer's check, ties
    included; a prefix in FPS order passes at its own length whatever order the rest of the cloud is in."""
    rng = np.random.default_rng(2)
    cloud = fps_reduced(rng.normal(size=(900, 3)), 200)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    tied = np.vstack([corners[0], corners[7], corners[1:7][[3, 0, 5, 1, 4, 2]], rng.uniform(0.2, 0.8, (192, 3))])
    clouds = [cloud, cloud[rng.permutation(200)], cloud[::-1].copy(), tied]
    answers = is_farthest_point_prefix(torch.from_numpy(np.stack(clouds)).float(), 200).tolist()
    assert answers == [is_farthest_point_ordered(c) for c in clouds] == [True, False, False, False]
    assert is_farthest_point_prefix(torch.from_numpy(tied[None, :8]).float(), 8).item()  # the corners' ties
    tail_shuffled = np.vstack([cloud[:50], cloud[50:][rng.permutation(150)]])[None]
    assert is_farthest_point_prefix(torch.from_numpy(tail_shuffled), 50).item()
    assert not is_farthest_point_prefix(torch.from_numpy(tail_shuffled), 200).item()


def test_sampling_cuts_clouds_in_fps_order_to_their_prefix_with_the_same_goals(monkeypatch):
    """Clouds as the project records them (FPS order, larger than the network's count) are cut to their prefix
    instead of reduced by FPS, and their layouts are prefixes too: the same goals, no FPS loop, no extra read."""
    torch.manual_seed(0)
    config = TaxDPDConfig.for_point_clouds(
        NUM_OBJECT, NUM_SCENE, hidden_dim=16, num_blocks=1, num_heads=2, point_scale=20.0, device="cpu"
    )
    policy = TaxDPDPolicy(config).eval()
    rng = np.random.default_rng(3)
    scene = make_slot_scene(rng, 4 * NUM_OBJECT, 4 * NUM_SCENE)
    obj = torch.from_numpy(fps_reduced(scene.object_points, 2 * NUM_OBJECT)[None]).float()
    scene_points = torch.from_numpy(fps_reduced(scene.scene_points, 2 * NUM_SCENE)[None]).float()

    def sample(counter: LaunchCounter) -> torch.Tensor:
        with device_code_paths(), counter:
            return policy.sample_goals(obj, scene_points, 4, generator=torch.Generator().manual_seed(4))

    cut = LaunchCounter()
    goals_cut = sample(cut)
    monkeypatch.setattr(
        modeling_taxdpd, "is_farthest_point_prefix", lambda points, count: torch.zeros(1, dtype=torch.bool)
    )
    reduced = LaunchCounter()
    goals_reduced = sample(reduced)
    torch.testing.assert_close(goals_cut, goals_reduced)
    assert cut.ops["other"].get("argmax", 0) == 0 and reduced.ops["other"]["argmax"] >= NUM_SCENE - 1
    assert cut.total_syncs() <= 2 and reduced.total_syncs() <= 2
    print(f"\nK = 4 call: {reduced.total_ops()} ops with FPS -> {cut.total_ops()} on clouds in FPS order")
