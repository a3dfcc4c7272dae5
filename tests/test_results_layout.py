"""results/ as an index (issue 38 item 2) and the results script's promises (RELIABILITY-4
defect #2): the generated results/README.md lists every current file and nothing else; a step
that fails leaves the committed table as it was; a stale step is rebuilt, a current one is not;
a mistyped section is one error line and exit status 2. Heavy steps are stubbed by small
commands: the engine is what is tested, not the tables."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "studies"))

import results_index  # noqa: E402
from results_steps import Step, table_steps  # noqa: E402

import results  # noqa: E402


def _links(index_text: str) -> set[str]:
    return {"results/" + m for m in re.findall(r"^\| \[[^\]]+\]\(([^)]+)\)", index_text, re.M)}


def test_committed_index_lists_every_result_and_nothing_missing():
    listed = _links((ROOT / "results/README.md").read_text())
    present = set(results_index.listed_files(ROOT))
    assert present - listed == set(), "not in results/README.md: rerun `uv run studies/results.py index`"
    assert listed - present == set(), "listed in results/README.md but absent"
    assert present, "no results found"


def test_results_top_level_is_a_handful_of_folders():
    top = {p.name for p in (ROOT / "results").iterdir() if not p.name.startswith(".")}
    assert top <= {"headline", "studies", "bench", "history", "runs", "README.md", "manifest.json"}
    assert (ROOT / "results/history/README.md").exists()


def test_every_step_writes_inside_the_layout_and_no_two_steps_share_an_output():
    outs = [o for s in table_steps() for o in s.outs]
    assert len(outs) == len(set(outs))
    assert all(o.startswith(("results/headline/", "results/studies/", "results/bench/")) for o in outs)


def test_every_model_a_step_reads_is_committed():
    """A step's archived models are in git (a typo or a shadowed prefix in results_steps.py
    once named 'looped_s{k}delayed_5m.zip': the step was kept 'as committed' for ever)."""
    tracked = set(subprocess.run(["git", "ls-files", "archive"], cwd=ROOT, capture_output=True,
                                 text=True, check=True).stdout.split())
    models = {i for s in table_steps() for i in s.inputs if i.endswith(".zip")}
    assert models and models <= tracked, sorted(models - tracked)


def _fake(tmp: Path, body: str) -> Step:
    """A step whose command is a tiny Python script (instead of runs.py or metrics.py)."""
    script = tmp / "fake_step.py"
    script.write_text(body)
    (tmp / "results").mkdir(exist_ok=True)
    (tmp / "input.txt").write_text("v1\n")
    return Step(("results/table.md",), (str(script),), ("input.txt",), stdout=True)


def test_a_failing_step_leaves_the_committed_table_intact(tmp_path, capsys):
    committed = "| a committed table |\n"
    (tmp_path / "results").mkdir()
    (tmp_path / "results/table.md").write_text(committed)
    step = _fake(tmp_path, "import sys\nprint('| half a table')\nsys.exit(1)\n")
    assert results.build(tmp_path, [step]) == 1
    assert (tmp_path / "results/table.md").read_text() == committed
    assert not [p for p in (tmp_path / "results").iterdir() if p.name.startswith(".step-")]
    assert "FAILED (exit status 1)" in capsys.readouterr().err


def test_a_step_that_writes_nothing_is_a_failure_too(tmp_path):
    (tmp_path / "results").mkdir()
    (tmp_path / "results/fig.png").write_bytes(b"old figure")
    step = Step(("results/fig.png",), (str(tmp_path / "noop.py"), "--plot", "{out0}"))
    (tmp_path / "noop.py").write_text("pass\n")
    assert results.build(tmp_path, [step]) == 1
    assert (tmp_path / "results/fig.png").read_bytes() == b"old figure"


def test_stale_steps_rebuild_and_current_ones_do_not(tmp_path):
    counter = tmp_path / "runs.log"
    step = _fake(tmp_path, f"open({str(counter)!r}, 'a').write('x')\nprint(open('input.txt').read())")
    assert results.build(tmp_path, [step]) == 0  # missing -> built
    table = (tmp_path / "results/table.md").read_text()
    made_by = f"Made by `uv run {tmp_path}/fake_step.py > results/table.md` at commit"
    assert table.splitlines()[0].startswith(made_by)
    assert "v1" in table
    assert results.build(tmp_path, [step]) == 0  # current -> not run
    assert counter.read_text() == "x"
    (tmp_path / "input.txt").write_text("v2\n")  # a changed input -> stale
    assert results.build(tmp_path, [step]) == 0
    assert counter.read_text() == "xx" and "v2" in (tmp_path / "results/table.md").read_text()
    (tmp_path / "results/table.md").unlink()  # a deleted output -> rebuilt
    assert results.build(tmp_path, [step]) == 0 and counter.read_text() == "xxx"
    assert results.build(tmp_path, [step], force=True) == 0 and counter.read_text() == "xxxx"


def test_a_folders_digest_ignores_machine_local_lock_files(tmp_path):
    (tmp_path / "runs" / "study").mkdir(parents=True)
    (tmp_path / "runs" / "study" / "seed_1.json").write_text("{}")
    before = results.digest(tmp_path, ("runs/study",))
    (tmp_path / "runs" / "study" / ".seed_1.json.lock").write_text("")
    assert results.digest(tmp_path, ("runs/study",)) == before
    (tmp_path / "runs" / "study" / "seed_2.json").write_text("{}")
    assert results.digest(tmp_path, ("runs/study",)) != before



    """Two `results.py --only` runs side by side: a stamp the other run saved while this one's
    step ran is still in the manifest after this one saves its own."""
    other = {"command": "uv run other.py", "commit": "abc", "inputs": "0"}
    manifest = tmp_path / "results" / "manifest.json"
    step = _fake(tmp_path, "import json\n"
                           f"p = {str(manifest)!r}\n"
                           "m = json.load(open(p))\n"
                           f"m['results/other.md'] = {other!r}\n"
                           "json.dump(m, open(p, 'w'))\n"
                           "print('| a table |')\n")
    manifest.write_text("{}\n")
    assert results.build(tmp_path, [step]) == 0
    stamps = json.loads(manifest.read_text())
    assert stamps["results/other.md"] == other
    assert stamps["results/table.md"]["command"].endswith("> results/table.md")


def test_a_step_whose_input_is_absent_keeps_its_table(tmp_path, capsys):
    (tmp_path / "results").mkdir()
    (tmp_path / "results/table.md").write_text("kept\n")
    step = Step(("results/table.md",), ("metrics.py",), ("rollouts/none",), stdout=True)
    assert results.build(tmp_path, [step]) == 0
    assert (tmp_path / "results/table.md").read_text() == "kept\n"
    assert "cannot rebuild here" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["tabels"], ["--onyl", "x"]])
def test_a_mistyped_command_line_is_one_error_line_and_exit_2(argv):
    before = (ROOT / "results/README.md").read_bytes()
    p = subprocess.run([sys.executable, "studies/results.py", *argv], cwd=ROOT,
                       capture_output=True, text=True)
    assert p.returncode == 2, p.stderr
    assert p.stderr.startswith("error: ") and len(p.stderr.strip().splitlines()) == 1
    assert p.stdout == ""
    assert (ROOT / "results/README.md").read_bytes() == before


def test_only_that_matches_nothing_is_a_user_error():
    with pytest.raises(SystemExit) as exc:
        results.main(["tables", "--only", "results/no_such/*", "--dry-run"])
    assert exc.value.code == 2


def test_prepare_summarizes_finished_runs_and_skips_a_stopped_trial(tmp_path, monkeypatch,
                                                                     capsys):
    """A sweep stopped mid-trial leaves a run folder with only interrupted_model.zip; runs.py
    summarize refuses a list holding one, so the `all` section must pass the finished ones."""
    import results_prepare

    runs = tmp_path / "sweeps" / "deploy_nominal_5m" / "runs"
    for name, files in (("t0000__3__1", ("best_model.zip", "final_model.zip")),
                        ("t0001__1__2", ("interrupted_model.zip",))):
        (runs / name).mkdir(parents=True)
        for f in files:
            (runs / name / f).write_bytes(b"")
    calls = []
    monkeypatch.setattr(results_prepare, "_run", lambda root, *argv: calls.append(argv))
    results_prepare.prepare(tmp_path)
    (summarize,) = [c for c in calls if c[1:2] == ("summarize",)]
    assert summarize[summarize.index("--runs") + 1:] == ("sweeps/deploy_nominal_5m/runs/t0000__3__1/",)
    assert "skip: sweeps/deploy_nominal_5m/runs/t0001__1__2/ is not a finished run" in \
        capsys.readouterr().out


def test_prepare_for_only_some_steps_plays_just_the_sets_they_read(tmp_path, monkeypatch):
    """results.py all --only GLOB prepares the registered rollout sets its steps read and
    nothing else (no sweep, no other set): here, on a bare root, one missing online set and a
    missing baseline."""
    import results_prepare

    calls = []
    monkeypatch.setattr(results_prepare, "_run", lambda root, *argv: calls.append(argv))
    results_prepare.prepare(tmp_path, {"feedforward_repetitive_noise1", "classical"})
    assert [c[:2] for c in calls] == [("ikpd.py", "--seeds"),
                                      ("studies/online_correction.py", "play")]
    play = calls[1]
    assert play[play.index("--prefix") + 1] == "feedforward_repetitive_noise1"
    assert play[play.index("--condition") + 1] == "noise1"
    assert play[play.index("--base") + 1] == "feedforward"
    calls.clear()
    results_prepare.prepare(tmp_path, set())
    assert calls == []


def test_a_failing_preparation_step_is_one_line_naming_it(tmp_path):
    """A script prepare runs that fails (another run playing the same set holds its lock, say)
    stops the run with one line naming it, not a traceback of subprocess's."""
    import results_prepare

    from panda_lead.errors import UserError

    (tmp_path / "fails.py").write_text("import sys\nprint('the reason')\nsys.exit(2)\n")
    with pytest.raises(UserError, match=r"`uv run fails.py --seeds 0-9 \.\.\.` exited 2"):
        results_prepare._run(tmp_path, "fails.py", "--seeds", "0-9", "--prefix", "x")
    results_prepare._run(tmp_path, "-c", "pass")  # a success says nothing


def test_the_long_episode_sets_are_played_at_their_length(tmp_path, monkeypatch):
    """The 10 s sets (results_prepare.LONG_EPISODES) on a bare root: each played once, at 10 s
    on test seeds 0-199, the corrected ones with their settings and gate."""
    import results_prepare

    calls = []
    monkeypatch.setattr(results_prepare, "_run", lambda root, *argv: calls.append(argv))
    monkeypatch.setattr(results_prepare, "_archived_sha", lambda root, name: "sha")
    results_prepare.prepare(tmp_path, set(results_prepare.LONG_EPISODES))
    played = {c[c.index("--prefix") + 1]: c for c in calls}
    assert set(played) == set(results_prepare.LONG_EPISODES)
    assert len(calls) == len(results_prepare.LONG_EPISODES)
    for argv in played.values():
        assert argv[argv.index("--duration") + 1] == "10.0"
        assert argv[argv.index("--seeds") + 1] == "0-199"
    gated = played["hardware_repetitive_guarded_10s"]
    assert gated[gated.index("--max-error") + 1] == "0.05" and "--model" in gated
    assert "--max-error" not in played["feedforward_repetitive_10s"]
    assert played["feedforward_10s"][:3] == ("ikpd.py", "--controller", "feedforward")
    seed = played["late100_s3_repetitive_guarded_10s"]
    assert seed[seed.index("--model") + 1].endswith("finetuned_late100_5m_s3.zip")


def test_results_all_only_hands_prepare_the_sets_of_the_selected_steps(monkeypatch):
    import results_prepare

    seen = []
    monkeypatch.setattr(results_prepare, "prepare", lambda root, needed=None: seen.append(needed))
    monkeypatch.setattr(results, "build", lambda *a, **k: 0)
    monkeypatch.setattr(results, "write_index", lambda *a, **k: None)
    results.main(["all", "--only", "results/studies/online/feedforward_repetitive_noise1_vs_*"])
    assert seen == [{"feedforward", "feedforward_repetitive_noise1"}]


def test_a_by_selection_spread_goes_stale_on_its_own_studys_scores_only():
    # runs.py report --by selection reads <study>_s<k>.json of the selection scores; with the
    # whole scores folder as its input, every other study's new score made it stale.
    from results_steps import BY_SELECTION

    for study in BY_SELECTION:
        step = next(s for s in table_steps() if s.outs == (f"results/studies/{study}/spread.md",))
        scores = [i for i in step.inputs if i.startswith("results/studies/rank/scores")]
        assert scores, f"{study}'s spread reads no selection score"
        assert all(re.fullmatch(rf"{re.escape(study)}_s\d+\.json", Path(i).name) for i in scores)
        assert all((ROOT / i).is_file() for i in scores)


def test_every_set_the_online_tables_read_is_one_prepare_plays():
    """A table of studies/results_online.py that read a rollout set no registry of
    results_prepare.py plays would stay "kept as committed" on every machine (its input never
    made): every set it reads is registered."""
    sys.path.insert(0, str(ROOT / "studies"))
    from results_online import online_steps
    from results_prepare import online_prefixes

    reads = {i.removeprefix("rollouts/") for step in online_steps() for i in step.inputs
             if i.startswith("rollouts/")}
    assert reads and reads <= online_prefixes(), sorted(reads - online_prefixes())


def test_the_excursions_table_counts_the_studys_sets_in_every_world():
    """excursions.md groups the hardware study's five seeds alone, corrected and gated, in each
    world, and the rival's sets (a later step once reused its variable and handed it the 10 s
    sets instead: results.py --dry-run said "made by another command")."""
    from results_online import online_steps

    (step,) = [s for s in online_steps() if s.outs[0].endswith("/excursions.md")]
    counted = {p for g in step.argv[step.argv.index("--groups") + 1:]
               for p in g.split("=")[1].split(",")}
    assert {i.removeprefix("rollouts/") for i in step.inputs} == counted  # reads what it counts
    for world in ("", "_delay3", "_noise1", "_noise1_plan"):
        for mid in ("", "_repetitive", "_repetitive_guarded"):
            assert f"late100_s3{mid}{world}" in counted
    assert {"feedforward", "feedforward_repetitive_noise1"} <= counted
    assert not [p for p in counted if p.endswith("_10s")]


def _prepare_bare(root, monkeypatch, registry: dict) -> tuple[list, dict]:
    """results_prepare.prepare on a bare root for one registry's sets, every script it would
    run recorded instead (each archived model's hash "sha"): the calls (kept: a test clears
    and reuses them) and prefix -> its call; each set played exactly once."""
    import results_prepare as rp

    calls = []
    monkeypatch.setattr(rp, "_run", lambda root, *argv: calls.append(argv))
    monkeypatch.setattr(rp, "_archived_sha", lambda root, name: "sha")
    rp.prepare(root, set(registry))
    played = {c[c.index("--prefix") + 1]: c for c in calls}
    assert set(played) == set(registry) and len(calls) == len(registry)
    return calls, played


def _plays(root, monkeypatch, calls: list, prefix: str, meta: dict) -> int:
    """How many scripts results_prepare.prepare runs for ``prefix`` when its first rollout
    records ``meta`` (``calls``: _prepare_bare's record of the scripts run, cleared first)."""
    import results_prepare as rp

    calls.clear()
    monkeypatch.setattr(rp, "_first_meta", lambda root, prefix, meta=meta: meta)
    rp.prepare(root, {prefix})
    return len(calls)


def test_the_collision_aware_sets_are_played_with_their_own_clearance(tmp_path, monkeypatch):
    """The collision-aware sets (results_prepare.CLEARANCE) on a bare root: each played once on
    the test seeds' 5 s episodes, the study's with the lead's clearance (eval.py's IK flag
    alone, the correction's flag with its gate), the rival's with its own; a set played with
    that clearance and setting is kept, one played with the plain IK is played again."""
    import results_prepare as rp

    calls, played = _prepare_bare(tmp_path, monkeypatch, rp.CLEARANCE)
    assert rp.CLEARANCE_LEAD != rp.CLEARANCE_RIVAL  # (so the checks below tell them apart)
    for prefix, argv in played.items():
        assert argv[argv.index("--seeds") + 1] == "0-999" and "--duration" not in argv
        flag = "--clearance" if "repetitive" in prefix else "--env.ik.clearance"
        want = rp.CLEARANCE_RIVAL if prefix.startswith("feedforward") else rp.CLEARANCE_LEAD
        assert float(argv[argv.index(flag) + 1]) == want
    gated = played["late100_s2_repetitive_guarded_clear"]
    assert gated[gated.index("--max-error") + 1] == "0.05"
    assert gated[gated.index("--model") + 1].endswith("finetuned_late100_5m_s2.zip")
    assert played["feedforward_clear"][:3] == ("ikpd.py", "--controller", "feedforward")
    assert "--max-error" not in played["feedforward_repetitive_clear"]

    spec = rp.CLEARANCE["late100_s1_repetitive_guarded_clear"][2]
    done = {"duration": 5.0, "model_sha256": "sha",
            "env": {"ik": {"clearance": rp.CLEARANCE_LEAD}},
            "online": {**dict(zip(rp.SETTINGS, spec[2:], strict=True)), "max_error": rp.GATE}}
    plain = {**done, "env": {"ik": {"clearance": 0.0}}}
    assert _plays(tmp_path, monkeypatch, calls, "late100_s1_repetitive_guarded_clear", done) == 0
    assert _plays(tmp_path, monkeypatch, calls, "late100_s1_repetitive_guarded_clear", plain) == 1


def test_the_faded_sets_are_played_with_their_fade_and_replayed_without_it(tmp_path, monkeypatch):
    """The faded corrections (results_prepare.FADED, FADED_CONDITION) on a bare root: each played
    once with its fade, the collision-aware ones with their controller's clearance, the latency
    ones under it; a set played with that fade is kept, one played with the correction switched
    on at once is played again (the fade is part of the setting a set must record)."""
    import results_prepare as rp

    calls, played = _prepare_bare(tmp_path, monkeypatch, rp.FADED)
    for prefix, argv in played.items():
        assert float(argv[argv.index("--fade") + 1]) == rp.FADE
        want = rp.CLEARANCE_RIVAL if prefix.startswith("feedforward") else rp.CLEARANCE_LEAD
        assert ("--clearance" in argv) == ("_clear" in prefix)
        if "_clear" in prefix:
            assert float(argv[argv.index("--clearance") + 1]) == want
    assert "--max-error" in played["late100_s4_repetitive_guarded_fade"]
    assert "--max-error" not in played["feedforward_repetitive_fade"]
    calls, played = _prepare_bare(tmp_path, monkeypatch, rp.FADED_CONDITION)
    for argv in played.values():  # through latency: its own fade, the ungated setting there
        assert argv[argv.index("--condition") + 1] == "delay3" and "--max-error" not in argv
        assert float(argv[argv.index("--fade") + 1]) == rp.FADE_DELAY3

    spec = rp.FADED["late100_s1_repetitive_guarded_fade"][2]
    at_once = {"duration": 5.0, "model_sha256": "sha", "env": {"ik": {"clearance": 0.0}},
               "online": {**dict(zip(rp.SETTINGS, spec[2:], strict=True)), "max_error": rp.GATE}}
    faded = {**at_once, "online": {**at_once["online"], "fade": rp.FADE}}
    assert _plays(tmp_path, monkeypatch, calls, "late100_s1_repetitive_guarded_fade", faded) == 0
    assert _plays(tmp_path, monkeypatch, calls, "late100_s1_repetitive_guarded_fade", at_once) == 1


def test_the_planned_sets_hand_over_to_the_plan_and_are_replayed_without_it(tmp_path, monkeypatch):
    """The planner's hand (results_prepare.PLANNED) on a bare root: the lead-alone sets through
    eval.py's env flag, the corrected ones through online_correction.py's, each with its faded
    setting; a set played with the plan is kept, one played without it is played again."""
    import results_prepare as rp

    calls, played = _prepare_bare(tmp_path, monkeypatch, rp.PLANNED)
    for prefix, argv in played.items():
        if "repetitive" in prefix:
            assert "--follow-plan" in argv and float(argv[argv.index("--fade") + 1]) == rp.FADE
            assert ("--clearance" in argv) == ("_clear" in prefix)
            if "_clear" in prefix:  # the collision-aware ones: each controller its clearance
                want = (rp.CLEARANCE_RIVAL if prefix.startswith("feedforward")
                        else rp.CLEARANCE_LEAD)
                assert float(argv[argv.index("--clearance") + 1]) == want
        else:
            assert argv[0] == "eval.py"
            assert argv[argv.index("--env.follow-plan") + 1] == "True"
    assert played["feedforward_repetitive_fade_plan"][3] == "feedforward"

    spec = rp.PLANNED["late100_s1_repetitive_guarded_fade_plan"][2]
    without = {"duration": 5.0, "model_sha256": "sha", "env": {"ik": {"clearance": 0.0}},
               "online": {**dict(zip(rp.SETTINGS, spec[2:], strict=True)), "max_error": rp.GATE,
                          "fade": rp.FADE}}
    with_plan = {**without, "env": {**without["env"], "follow_plan": True}}
    prefix = "late100_s1_repetitive_guarded_fade_plan"
    assert _plays(tmp_path, monkeypatch, calls, prefix, with_plan) == 0
    assert _plays(tmp_path, monkeypatch, calls, prefix, without) == 1


def test_the_hand_trained_study_is_played_like_its_control(tmp_path, monkeypatch):
    """The fine-tune trained with the hand (results_prepare.LATE100_HAND) is played as its
    control (the hardware study) is: its own seed's model, with the hand, and corrected with
    the hardware study's setting, gate and fade; only the model differs."""
    import results_prepare as rp

    hand = {p: v for p, v in rp.PLANNED.items() if p.startswith("late100hand_")}
    assert len(hand) == 10
    _, played = _prepare_bare(tmp_path, monkeypatch, hand)
    for k in range(1, 6):
        model = f"archive/seeds/{rp.LATE100_HAND}_s{k}.zip"
        alone = played[f"late100hand_s{k}_plan"]
        assert alone[alone.index("--model") + 1] == model
        assert alone[alone.index("--env.follow-plan") + 1] == "True"
        ours = played[f"late100hand_s{k}_repetitive_guarded_fade_plan"]
        control = rp.PLANNED[f"late100_s{k}_repetitive_guarded_fade_plan"]
        assert ours[ours.index("--model") + 1] == model and "--follow-plan" in ours
        setting = [ours[ours.index(flag) + 1] for flag in ("--gain", "--advance", "--smooth")]
        assert setting == [str(x) for x in control.spec[3:]]
        assert float(ours[ours.index("--max-error") + 1]) == control.gate == rp.GATE
        assert float(ours[ours.index("--fade") + 1]) == control.fade == rp.FADE


def test_a_baselines_file_without_a_rival_added_later_is_completed(tmp_path):
    """results_prepare runs runs.py baselines when the file is missing or lacks one of
    runs.BASELINES (the command then computes only the missing ones)."""
    import json

    import results_prepare as rp
    from runs import BASELINES

    path = tmp_path / "results/runs/baselines.json"
    assert rp._baselines_missing(tmp_path)
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps({"test_seeds": "0-999", **{n: {} for n in BASELINES}}))
    assert not rp._baselines_missing(tmp_path)
    path.write_text(json.dumps({n: {} for n in BASELINES if n != "feedforward_plan"}))
    assert rp._baselines_missing(tmp_path)


def test_the_hand_under_latency_and_noise_is_played_in_its_condition(tmp_path, monkeypatch):
    """results_prepare.PLANNED_CONDITION: each set played once with --follow-plan under its
    condition (latency 3 ungated, noise on the plan gated, the rival's as registered there); a
    set played in that condition without the hand is played again."""
    import results_prepare as rp

    calls, played = _prepare_bare(tmp_path, monkeypatch, rp.PLANNED_CONDITION)
    for prefix, argv in played.items():
        assert "--follow-plan" in argv
        want = "delay3" if "delay3" in prefix else ("noise1_plan" if "late100" in prefix
                                                    else "noise1")
        assert argv[argv.index("--condition") + 1] == want
        assert ("--max-error" in argv) == ("guarded" in prefix)
    spec, condition, gate = rp.PLANNED_CONDITION["late100_s2_repetitive_delay3_hand"]
    from online_correction import condition_overrides

    without = {"model_sha256": "sha", "env": condition_overrides(condition, "policy"),
               "online": dict(zip(rp.SETTINGS, spec[2:], strict=True))}
    with_hand = {**without, "env": {**without["env"], "follow_plan": True}}
    assert _plays(tmp_path, monkeypatch, calls, "late100_s2_repetitive_delay3_hand", with_hand) == 0
    assert _plays(tmp_path, monkeypatch, calls, "late100_s2_repetitive_delay3_hand", without) == 1
