"""Goal scorers: labelled samples collected from real executions in legs, a scorer that learns to choose the
sample that works where the first one usually does not, and the evaluation option that uses it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from lerobot_taxdpd.goal_predictors import load_scorer, resolve_goal_predictor, resolve_scorer, weights_digest
from lerobot_taxdpd.maths.selection import executed_first
from lerobot_taxdpd.policies.goal_scorer import GoalScorer, GoalScorerConfig, search_shifts
from lerobot_taxdpd.scoring.collect import COLLECTION_FILE, SHARD_ARRAYS, collect, load_collection
from lerobot_taxdpd.scoring.shipping import commands, evaluate_choice, ship_scorer
from lerobot_taxdpd.scoring.training import train_scorer
from lerobot_taxdpd.sim.cli import main as sim_main
from lerobot_taxdpd.sim.cloth.evaluation import TrialRequest, run_trial


def test_the_scorer_rule_executes_the_highest_scored_sample():
    samples = np.arange(4 * 2 * 3, dtype=float).reshape(4, 2, 3)
    reordered, index = executed_first(samples, "scorer", radius=0.02, scores=np.array([0.1, -2.0, 3.0, 0.5]))
    assert index == 2
    np.testing.assert_array_equal(reordered, samples[[2, 0, 1, 3]])
    with pytest.raises(ValueError, match="needs one score per sample"):
        executed_first(samples, "scorer", radius=0.02)


@pytest.fixture
def one_torch_thread():
    """One torch thread in this process, as in each of the collector's worker processes (and under `make test`):
    a matmul split over two threads rounds differently, and parallel shards must equal one process's to the bit."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_collection_executes_every_sample_runs_in_legs_and_refuses_other_options(tmp_path, capsys, one_torch_thread):
    folder = tmp_path / "collection"
    first = collect("mug_easyrack", "mug_easyrack", range(5000, 5001), folder, num_samples=3, shard_size=1)
    assert [p.name for p in first] == ["shard_005000_005000.npz"]
    stamp = first[0].stat().st_mtime_ns
    both = collect("mug_easyrack", "mug_easyrack", range(5000, 5002), folder, num_samples=3, shard_size=1)
    assert len(both) == 2 and both[0].stat().st_mtime_ns == stamp, "a second leg adds shards, keeps the first"
    assert not list(folder.glob("*.partial*")), "no half-written shard is left behind"
    details, data = load_collection(folder)
    assert details["task"] == "mug_easyrack" and details["split"] == "train" and details["num_samples"] == 3
    assert set(data) == set(SHARD_ARRAYS) and data["seed"].tolist() == [5000, 5001]
    assert data["samples"].shape[:2] == (2, 3) and data["samples"].shape[2:] == data["object"].shape[1:]
    assert data["success"].dtype == bool and data["success"].shape == (2, 3)
    # Success is the executed outcome, not the distance: a sample far from every valid goal never succeeds.
    assert not data["success"][data["rmse"] > 0.05].any()
    # Shards labelled by two processes hold what one process labels: each scene's samples and outcomes come
    # from its seed alone.
    parallel = collect("mug_easyrack", "mug_easyrack", range(5000, 5002), tmp_path / "parallel", num_samples=3,
                       shard_size=1, workers=2, progress=False)  # fmt: skip
    assert [p.name for p in parallel] == [p.name for p in both]
    for name, values in load_collection(tmp_path / "parallel")[1].items():
        np.testing.assert_array_equal(values, data[name], err_msg=name)
    with pytest.raises(ValueError, match="num_samples 3, not 4"):
        collect("mug_easyrack", "mug_easyrack", range(5002, 5003), folder, num_samples=4, shard_size=1)
    assert json.loads((folder / COLLECTION_FILE).read_text())["num_samples"] == 3

    # A scorer of these samples, used with their predictor and with another one: only the second is warned.
    train_scorer(folder, tmp_path / "scorer", steps=2, config=GoalScorerConfig(hidden_dims=(16,), feature_dim=16))
    common = ["eval", "--trials", "1", "--figures", "0", "--scorer.path", str(tmp_path / "scorer")]
    for task, warned in (("mug_easyrack", False), ("mug_medrack", True)):
        assert sim_main([*common, "--task", task, "--goal-policy.path", task, "--output", str(tmp_path / task)]) == 0
        report = json.loads((tmp_path / task / f"{task}_eval.json").read_text())
        assert report["goal_selection"] == "scorer" and report["scorer"] == str(tmp_path / "scorer")
        assert ("trained on the samples of another goal predictor" in capsys.readouterr().err) == warned

    # Shipped beside its predictor, with a paired evaluation and the commands that remake it; not beside another.
    evaluation = evaluate_choice("mug_easyrack", "mug_easyrack", str(tmp_path / "scorer"), range(1), num_samples=3)
    assert sum(evaluation["paired"].values()) == 1 and evaluation["baseline"]["trials"] == 1
    assert evaluation["baseline_rule"] == "first"
    shipped = ship_scorer(tmp_path / "scorer", "mug_easyrack", evaluation, tmp_path / "pretrained")
    assert shipped == tmp_path / "pretrained" / "mug_easyrack" / "scorer"
    assert load_scorer(shipped).config == load_scorer(tmp_path / "scorer").config
    card = (shipped / "README.md").read_text()
    assert "python -m lerobot_taxdpd.scoring collect --task mug_easyrack --goal-policy.path mug_easyrack" in card
    assert str(tmp_path) not in card and "the scorer's choice" in card
    with pytest.raises(ValueError, match="trained on the samples of goal predictor weights"):
        ship_scorer(tmp_path / "scorer", "mug_medrack", evaluation, tmp_path / "elsewhere")
    assert not (tmp_path / "elsewhere").exists()

    # Shipped with a search around its samples: measured with and without it on the same samples, paired, and
    # the search lands in the shipped config, so the predictor's name brings it.
    search = {"search_extent_mm": 3.0}
    searched = evaluate_choice("mug_easyrack", "mug_easyrack", str(tmp_path / "scorer"), range(1), num_samples=3,
                               search=search)  # fmt: skip
    assert searched["search"] == {"extent_mm": 3.0, "step_mm": 3.0} and sum(searched["paired_search"].values()) == 1
    shipped = ship_scorer(tmp_path / "scorer", "mug_easyrack", searched, tmp_path / "searching", search=search)
    assert load_scorer(shipped).config.search_extent_mm == 3.0
    assert load_scorer(tmp_path / "scorer").config.search_extent_mm == 0.0, "the trained scorer is left as it was"
    card = (shipped / "README.md").read_text()
    assert "moved by its search (up to 3 mm in x and y" in card and "--search-extent-mm 3" in card

    # Shifted copies for a searching scorer: the scene's samples first, as collected without them, then copies
    # of them moved rigidly in x and y within the extent, each executed.
    collect("mug_easyrack", "mug_easyrack", range(5000, 5001), tmp_path / "shifted", num_samples=3, shard_size=1,
            shifted_copies=2, shift_extent_mm=9.0)  # fmt: skip
    details, shifted = load_collection(tmp_path / "shifted")
    assert details["shifted_copies"] == 2 and shifted["success"].shape == (1, 5)
    np.testing.assert_array_equal(shifted["samples"][0, :3], data["samples"][0])
    moved = shifted["samples"][0, 3:, None] - shifted["samples"][0, None, :3]  # (copies, K, N, 3)
    offsets = moved.mean(2)
    rigid = np.abs(moved - offsets[:, :, None]).max((2, 3))
    source = rigid.argmin(1)
    offsets = offsets[[0, 1], source]
    assert (rigid[[0, 1], source] < 1e-5).all()
    assert (np.abs(offsets[:, :2]) <= 0.009 + 1e-6).all() and (np.abs(offsets[:, 2]) < 1e-6).all()


def _box_collection(folder: Path, rng, scenes: int, k: int, candidates) -> dict[str, np.ndarray]:
    """A synthetic collection in `folder`: a shelf board and a box (bottom face at z = 0) that starts above it;
    `candidates(rng, start)` gives each scene's K box offsets (K, 3) and which of them succeed (K,)."""
    board = np.concatenate([rng.uniform(-0.3, 0.3, (200, 2)), np.zeros((200, 1))], 1)
    box = rng.uniform(-0.04, 0.04, (64, 3)) + [0, 0, 0.04]
    data = {"seed": [], "scene": [], "object": [], "samples": [], "success": [], "rmse": []}
    for seed in range(scenes):
        start = np.append(rng.uniform(-0.2, 0.2, 2), 0.1)
        places, success = candidates(rng, start)
        data["samples"].append(box[None] + places[:, None])
        data["success"].append(success)
        data["rmse"].append(np.abs(places[:, 2]))
        data["seed"].append(seed)
        data["scene"].append(board + rng.normal(0, 0.001, board.shape))
        data["object"].append(box + start)
    arrays = {name: np.asarray(values) for name, values in data.items()}
    folder.mkdir()
    np.savez(folder / f"shard_000000_{scenes - 1:06d}.npz",
             **{name: v.astype(np.float32) if v.dtype == float else v for name, v in arrays.items()})  # fmt: skip
    (folder / COLLECTION_FILE).write_text(json.dumps({"task": "synthetic box", "num_samples": k}))
    return arrays


def _one_resting(rng, start, k: int = 8):
    """One of the K candidate boxes rests on the board, the others float 2-6 cm above it or cut 2-6 cm into it,
    at random places. Success: the resting one."""
    heights = rng.choice([-1, 1], k) * rng.uniform(0.02, 0.06, k)
    heights[rng.integers(k)] = 0.0
    return np.concatenate([rng.uniform(-0.2, 0.2, (k, 2)), heights[:, None]], 1), heights == 0.0


def _one_within_reach(rng, start, k: int = 8):
    """Every candidate box rests on the board at a random place, so the scene alone cannot tell them apart; the
    one that works is within 5 cm of where the box starts (an executor that cannot carry it far)."""
    places = np.concatenate([rng.uniform(-0.2, 0.2, (k, 2)), np.zeros((k, 1))], 1)
    places[rng.integers(k), :2] = start[:2] + rng.uniform(-0.03, 0.03, 2)
    return places, np.linalg.norm(places[:, :2] - start[:2], axis=1) <= 0.05


def test_a_trained_scorer_picks_the_sample_that_rests_where_the_first_one_rarely_does(tmp_path):
    folder = tmp_path / "collection"
    arrays = _box_collection(folder, np.random.default_rng(0), scenes=120, k=8, candidates=_one_resting)
    torch.manual_seed(0)
    config = GoalScorerConfig(num_goal_points=64, hidden_dims=(32, 64), feature_dim=64)
    metrics = train_scorer(
        folder, tmp_path / "scorer", steps=300, batch_scenes=8, validation_fraction=0.25, config=config
    )
    held = metrics["held_back_scenes"]
    print(f"held-back scenes: scorer {held['scorer']:.2f}, first sample (baseline) {held['first_sample']:.2f}")
    assert held["scenes"] == 30 and held["any_sample"] == 1.0
    assert held["first_sample"] < 0.3, "the trivial choice must fail this task for the test to mean anything"
    assert held["scorer"] >= 0.8 and held["pairs_ordered"] >= 0.8 and held["pairs"] == 30 * 7
    reloaded = load_scorer(tmp_path / "scorer")
    samples, scene = torch.from_numpy(arrays["samples"][0]).float(), torch.from_numpy(arrays["scene"][0]).float()
    trained = GoalScorer.from_pretrained(tmp_path / "scorer")
    torch.testing.assert_close(reloaded.score(samples, scene), trained.score(samples, scene))


def test_the_start_displacement_lets_a_scorer_see_what_the_scene_alone_cannot(tmp_path):
    folder = tmp_path / "collection"
    arrays = _box_collection(folder, np.random.default_rng(1), scenes=120, k=8, candidates=_one_within_reach)
    held = {}
    for displacement in (False, True):
        torch.manual_seed(0)
        config = GoalScorerConfig(num_goal_points=64, hidden_dims=(32, 64), feature_dim=64,
                                  start_displacement=displacement)  # fmt: skip
        metrics = train_scorer(folder, tmp_path / f"scorer_{displacement}", steps=300, validation_fraction=0.25,
                               config=config)  # fmt: skip
        held[displacement] = metrics["held_back_scenes"]
    print(f"held-back scenes: first sample (baseline) {held[True]['first_sample']:.2f}, scene alone "
          f"{held[False]['scorer']:.2f}, with the start displacement {held[True]['scorer']:.2f}")  # fmt: skip
    assert held[True]["first_sample"] < 0.4 and held[False]["scorer"] < 0.5
    assert held[True]["scorer"] >= 0.8
    scorer = load_scorer(tmp_path / "scorer_True")
    samples, scene = torch.from_numpy(arrays["samples"][0]).float(), torch.from_numpy(arrays["scene"][0]).float()
    with pytest.raises(ValueError, match="give the start cloud"):
        scorer.score(samples, scene)


def test_eval_options_of_the_scorer_are_checked_before_any_trial(tmp_path, capsys):
    common = ["eval", "--trials", "1", "--figures", "0", "--output", str(tmp_path)]
    assert sim_main([*common, "--task", "mug_easyrack", "--goal-policy.path", "mug_easyrack",
                     "--scorer.path", str(tmp_path), "--goal-selection", "first"]) != 0  # fmt: skip
    assert "--scorer.path: only used with --goal-selection scorer" in capsys.readouterr().err
    assert sim_main([*common, "--task", "mug_easyrack", "--goal-policy.path", "mug_easyrack",
                     "--goal-selection", "scorer"]) != 0  # fmt: skip
    assert "unknown goal scorer 'mug_easyrack'" in capsys.readouterr().err
    assert sim_main([*common, "--task", "book_shelf", "--goal-policy.path", "book_shelf", "--goal-selection",
                     "scorer", "--scorer.search-extent-mm", "-1"]) != 0  # fmt: skip
    assert "--search-extent-mm must be >= 0" in capsys.readouterr().err
    assert not (tmp_path / "book_shelf_eval.json").exists()
    assert sim_main([*common, "--task", "cloth_hang", "--goal-policy.path", "cloth_hang", "--policy.path",
                     "cloth_hang", "--goal-selection", "scorer", "--scorer.search-extent-mm", "3"]) != 0  # fmt: skip
    assert "the scorer's search around its samples is for rigid tasks" in capsys.readouterr().err
    with pytest.raises(ValueError, match="search around its samples is for rigid tasks"):
        evaluate_choice("cloth_hang", "cloth_hang", resolve_scorer("cloth_hang"), range(1),
                        search={"search_extent_mm": 3.0})  # fmt: skip
    assert sim_main([*common, "--task", "cloth_hang", "--goal-policy.path", "cloth_hang",
                     "--scorer.path", str(tmp_path)]) != 0  # fmt: skip
    assert f"--scorer.path {tmp_path}: {tmp_path}: not a goal scorer checkpoint (no config.json)" in (
        capsys.readouterr().err
    )


@pytest.mark.slow
def test_cloth_samples_are_labelled_by_the_executor_hanging_each_one(tmp_path, capsys):
    """cloth_hang: each sampled goal is hung by the shipped gc_dp3 executor; its outcome is the label."""
    folder = tmp_path / "cloth"
    collect("cloth_hang", "cloth_hang", range(5000, 5001), folder, num_samples=2, shard_size=1)
    details, data = load_collection(folder)
    assert details["executor"] == "cloth_hang" and details["executor_weights"] != "unknown"
    assert data["samples"].shape[:2] == (1, 2) and data["success"].shape == (1, 2)
    # Each label's RMSE is the one `sim eval` reports for the same sample of the same scene.
    evaluated = run_trial(TrialRequest(
        split="train", seed=5000, policy_path=None, goal_policy_path="cloth_hang", ground_truth_goals=False,
        num_goal_samples=2, goal_selection="first", compared_selections=(), goal_threshold=0.5, scorer_path=None,
        figure_dir=None, device="cpu", torch_threads=1,
    ))  # fmt: skip
    assert np.isfinite(data["rmse"]).all()
    np.testing.assert_allclose(data["rmse"][0], evaluated["sample_goal_rmse"], rtol=1e-5)
    # Its scorer measured on a held-out scene against the consensus sample (cloth's default) and the first, in
    # one pass, and shipped with the three rules in its card.
    config = GoalScorerConfig(num_goal_points=64, hidden_dims=(16,), feature_dim=16)
    train_scorer(folder, tmp_path / "scorer", steps=2, config=config)
    evaluation = evaluate_choice("cloth_hang", "cloth_hang", str(tmp_path / "scorer"), range(1), num_samples=2)
    assert evaluation["baseline_rule"] == "consensus" and sum(evaluation["paired"].values()) == 1
    assert {"scorer", "consensus", "first", "best_of_k"} == set(evaluation["executed_goal_valid"])
    report = json.loads(Path(evaluation["report"]).read_text())
    assert report["config"]["goal_selection"] == "scorer" and report["config"]["policy_path"].endswith("executor")
    shipped = ship_scorer(tmp_path / "scorer", "cloth_hang", evaluation, tmp_path / "pretrained")
    card = (shipped / "README.md").read_text()
    assert "| consensus (the sample the others agree with) |" in card and "executed goal valid" in card
    assert "--goal-policy.path cloth_hang --policy.path cloth_hang --goal-selection scorer" in card
    # `sim eval --ship` ships the pipeline with a rule that needs no scorer: the scorer's choice is refused before
    # any trial, and a scorer compared beside the consensus lands in the goal predictor's card.
    argv = ["eval", "--task", "cloth_hang", "--goal-policy.path", "cloth_hang", "--policy.path", "cloth_hang",
            "--scorer.path", str(tmp_path / "scorer"), "--trials", "1", "--num-samples", "2", "--figures", "0",
            "--output", str(tmp_path / "eval"), "--ship", str(tmp_path / "pipeline")]  # fmt: skip
    assert sim_main(argv) != 0 and not (tmp_path / "pipeline").exists()
    assert "ship a scorer with python -m lerobot_taxdpd.scoring ship" in capsys.readouterr().err
    assert sim_main([*argv, "--goal-selection", "consensus", "--compare-selections", "scorer", "first"]) == 0
    predictor_card = (tmp_path / "pipeline" / "cloth_hang" / "README.md").read_text()
    assert "consensus sample executed by gc_dp3" in predictor_card
    assert "chosen by another rule and executed alike: scorer" in predictor_card
    with pytest.raises(ValueError, match="only cloth_hang executes its goals with a policy"):
        collect("mug_easyrack", "mug_easyrack", range(1), tmp_path / "rigid", executor="cloth_hang")


def test_the_search_executes_the_best_rated_shifted_copy_of_a_sample():
    """With a search the scorer executes a sample moved within its grid, rated at least as high as any sample as
    sampled; without one it is the plain pick. The shipped book scorer on a held-out book scene."""
    from lerobot_taxdpd.goal_predictors import load_goal_predictor
    from lerobot_taxdpd.sim.harness import sample_trial_goals
    from lerobot_taxdpd.sim.predictors import observed_as_trained
    from lerobot_taxdpd.sim.tasks import get_task
    from lerobot_taxdpd.sim.trials import make_trial

    grid = search_shifts(6.0, 3.0)
    assert len(grid) == 25 and grid[0].abs().sum() == 0 and grid[:, 2].abs().max() == 0
    assert grid.abs().max() == pytest.approx(0.006) and len(search_shifts(0.0, 3.0)) == 1
    predictor, scorer = load_goal_predictor("book_shelf"), load_scorer("book_shelf")
    trial = make_trial(observed_as_trained(get_task("book_shelf"), predictor), 1000)
    samples = torch.from_numpy(sample_trial_goals(predictor, trial, 4))
    scene, start = torch.from_numpy(trial.scene_points), torch.from_numpy(trial.object_points)
    plain_scores = scorer.score(samples, scene, start)
    scorer.config.search_extent_mm = 0.0
    plain = scorer.choose(samples, scene, start)
    assert plain.index == int(plain_scores.argmax()) and plain.shift.abs().sum() == 0
    torch.testing.assert_close(plain.scores, plain_scores)
    torch.testing.assert_close(plain.goal, samples[plain.index])
    scorer.config.search_extent_mm = 6.0
    moved = scorer.choose(samples, scene, start)
    assert (moved.scores >= plain_scores - 1e-5).all() and moved.scores.max() == moved.scores[moved.index]
    assert moved.shift.abs().max() <= 0.006 + 1e-9 and moved.shift[2] == 0
    torch.testing.assert_close(moved.goal, samples[moved.index] + moved.shift.double())
    torch.testing.assert_close(scorer.score(moved.goal[None], scene, start)[0], moved.scores[moved.index])


def test_a_shipped_scorer_is_found_by_its_predictors_name(tmp_path):
    """`--goal-selection scorer` alone takes the scorer shipped beside the goal predictor of that name."""
    output = tmp_path / "eval"
    assert sim_main(["eval", "--task", "book_shelf", "--goal-policy.path", "book_shelf", "--goal-selection",
                     "scorer", "--trials", "1", "--figures", "0", "--output", str(output)]) == 0  # fmt: skip
    report = json.loads((output / "book_shelf_eval.json").read_text())
    assert report["goal_selection"] == "scorer" and report["scorer"] == "book_shelf"
    # The book's scorer ships with its search on: the executed goal moved within its horizontal grid.
    extent = load_scorer("book_shelf").config.search_extent_mm
    shift = report["per_trial"][0]["executed_shift_mm"]
    assert extent > 0 and max(abs(shift[0]), abs(shift[1])) <= extent and shift[2] == 0
    card = json.loads((Path(resolve_scorer("book_shelf")) / "metrics.json").read_text())
    assert card["collection"]["goal_policy_weights"] == weights_digest(resolve_goal_predictor("book_shelf"))


def test_a_cards_commands_remake_the_scorer_as_it_was_trained():
    """One collect command per run of consecutive seeds (collections made in legs leave gaps), and the train
    command with the options that changed the scorer, as anyone can type them."""
    metrics = {
        "collection": {"num_samples": 10, "executor": "cloth_hang"},
        "collected_seeds": "5000..5109, 5300..5409",
        "steps": 2000, "batch_scenes": 8, "seed": 0, "num_goal_points": 256, "start_displacement": True,
    }  # fmt: skip
    *collect, train = commands(metrics, "cloth_hang")
    assert [line.split("--seeds ")[1].split(" --")[0] for line in collect] == ["5000 5109", "5300 5409"]
    assert all("--executor" not in line for line in collect), "the executor shipped with the predictor's name"
    assert train.endswith("--seed 0 --num-goal-points 256 --start-displacement")
    searching = {**metrics, "search_extent_mm": 9.0, "search_step_mm": 3.0,
                 "collection": {"num_samples": 20, "shifted_copies": 20, "shift_extent_mm": 9.0}}  # fmt: skip
    *collected, searched = commands(searching, "book_shelf")
    assert searched.endswith("--start-displacement --search-extent-mm 9 --search-step-mm 3")
    assert all(line.endswith("--num-samples 20 --shifted-copies 20 --shift-extent-mm 9") for line in collected)
