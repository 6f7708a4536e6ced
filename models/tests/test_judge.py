"""The shipping rule (nedrt_train.judge): the verdict on the four headline
numbers and their SSIMs, the log entry written whether the network ships or
not, and --ship replacing the shipped files only when the rule passes and
the card's DOE is the one it names. `nedrt eval` is replaced by its
results (eval.json's rows), so no binary runs here."""
import hashlib
import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from nedrt_train import judge


def headline(mean_t, worst_t, mean_s, worst_s, ssim=0.8):
    """An eval.json row's headlines; `ssim` one value or four."""
    s = ssim if isinstance(ssim, tuple) else (ssim,) * 4
    x = lambda p, q: {"psnr_db": p, "ssim": q}  # noqa: E731
    return {"headline_vs_target": {"mean": x(mean_t, s[0]), "worst": x(worst_t, s[1])},
            "headline_vs_sharp": {"mean": x(mean_s, s[2]), "worst": x(worst_s, s[3])}}


# The H200's network of 2026-11-26 against its Wiener (docs/benchmarks.md).
H200 = {"methods": [{"method": "proposed", **headline(29.49, 24.51, 24.51, 22.75, (0.854, 0.737, 0.712, 0.652))},
                    {"method": "doe+wiener", **headline(29.75, 23.60, 23.83, 22.51, (0.838, 0.689, 0.683, 0.650))}]}
SHIPPED = {"methods": [{"method": "proposed", **headline(29.90, 23.63, 23.86, 22.55, (0.838, 0.689, 0.683, 0.651))}]}


def repo_with_candidate(tmp_path):
    """A repository with a shipped network, and a candidate whose card
    names a DOE under designs/."""
    repo = tmp_path / "repo"
    (repo / "models").mkdir(parents=True)
    (repo / "designs").mkdir()
    for name, data in (("dcnn.onnx", b"old net"), ("dcnn.card.json", b"{}"), ("dcnn.doe.safetensors", b"old doe")):
        (repo / "models" / name).write_bytes(data)
    doe = b"new doe"
    (repo / "designs" / "doe.safetensors").write_bytes(doe)
    out = repo / "out"
    out.mkdir()
    cand = out / "dcnn-full.onnx"
    cand.write_bytes(b"new net")
    card = {"steps": 10248, "wall_time_s": 290.0, "config": {"width": 32, "teacher_set": "train"},
            "doe": {"source": "designs/doe.safetensors", "sha256": hashlib.sha256(doe).hexdigest()}}
    cand.with_suffix(".card.json").write_text(json.dumps(card))
    (repo / "training.md").write_text("# Training\n\nThe log.\n")
    return repo, cand


def args(repo, cand, **kw):
    a = dict(candidate=str(cand), shipped=str(repo / "models" / "dcnn.onnx"), images="data/images/val",
             design="multifocal", nedrt="nedrt", log=str(repo / "training.md"), ship=False, note="",
             date="2026-11-27", repo=str(repo), models=str(repo / "models"))
    a.update(kw)
    return SimpleNamespace(**a)


def fake_eval(results):
    """`nedrt eval` answering the candidate's run, then the shipped one's."""
    calls = []

    def evaluate(nedrt, design, images, model, methods, out):
        calls.append((Path(model).name, methods))
        return results[methods]
    evaluate.calls = calls
    return evaluate


def test_the_h200_network_does_not_ship_and_the_log_says_which_number_fails(tmp_path, capsys):
    repo, cand = repo_with_candidate(tmp_path)
    ev = fake_eval({"proposed,doe+wiener": H200, "proposed": SHIPPED})
    assert judge.judge(args(repo, cand, ship=True), evaluate=ev) == 0
    assert ev.calls == [("dcnn-full.onnx", "proposed,doe+wiener"), ("dcnn.onnx", "proposed")]
    log = (repo / "training.md").read_text()
    assert judge.LOG_HEADING in log and log.startswith("# Training\n\nThe log.\n")
    assert "**does not ship**: mean vs target 29.49 dB is not above its Wiener's 29.75." in log
    assert "| candidate | 29.49 / 24.51 (0.854 / 0.737) | 24.51 / 22.75 (0.712 / 0.652) |" in log
    assert "| shipped (`" in log and "29.90 / 23.63" in log
    assert "Card: width 32, 10248 steps, 290 s, teacher set train." in log
    # Nothing shipped.
    assert (repo / "models" / "dcnn.onnx").read_bytes() == b"old net"
    assert "does not ship" in capsys.readouterr().out
    # A second judgement adds an entry under the same heading.
    judge.judge(args(repo, cand), evaluate=fake_eval({"proposed,doe+wiener": H200, "proposed": SHIPPED}))
    log = (repo / "training.md").read_text()
    assert log.count(judge.LOG_HEADING) == 1 and log.count("### 2026-11-27") == 2


def test_a_network_above_its_wiener_everywhere_ships_with_its_doe(tmp_path):
    repo, cand = repo_with_candidate(tmp_path)
    better = {"methods": [{"method": "proposed", **headline(30.0, 24.0, 24.6, 22.8, 0.85)},
                          {"method": "doe+wiener", **headline(29.75, 23.60, 23.83, 22.51, 0.84)}]}
    # Without --ship it passes, is logged, and nothing moves.
    judge.judge(args(repo, cand, shipped="none"), evaluate=fake_eval({"proposed,doe+wiener": better}))
    assert "**passes the rule**" in (repo / "training.md").read_text()
    assert (repo / "models" / "dcnn.onnx").read_bytes() == b"old net"
    judge.judge(args(repo, cand, shipped="none", ship=True), evaluate=fake_eval({"proposed,doe+wiener": better}))
    assert "**ships**" in (repo / "training.md").read_text()
    models = repo / "models"
    assert (models / "dcnn.onnx").read_bytes() == b"new net"
    assert (models / "dcnn.doe.safetensors").read_bytes() == b"new doe"
    assert json.loads((models / "dcnn.card.json").read_text())["steps"] == 10248
    assert not list(models.glob(".dcnn*"))


def test_a_lower_ssim_or_a_tie_fails_the_rule():
    w = judge.Scores("w", {n: (20.0, 0.8) for _, _, n in judge.HEADLINES})
    c = judge.Scores("c", {n: (21.0, 0.8) for _, _, n in judge.HEADLINES})
    assert judge.verdict(c, w) == []
    c.numbers["worst vs sharp"] = (21.0, 0.79)
    c.numbers["mean vs target"] = (20.0, 0.9)
    assert judge.verdict(c, w) == ["mean vs target 20.00 dB is not above its Wiener's 20.00",
                                   "SSIM worst vs sharp 0.790 is below its Wiener's 0.800"]
    # Differences below the tables' precision decide nothing: 0.0002 SSIM
    # lower is not lower, 0.004 dB above is not above.
    c.numbers["worst vs sharp"] = (21.0, 0.7998)
    c.numbers["mean vs target"] = (20.004, 0.9)
    assert judge.verdict(c, w) == ["mean vs target 20.00 dB is not above its Wiener's 20.00"]


def test_a_card_whose_doe_is_not_the_named_one_is_not_shipped(tmp_path):
    repo, cand = repo_with_candidate(tmp_path)
    (repo / "designs" / "doe.safetensors").write_bytes(b"another doe")
    better = {"methods": [{"method": "proposed", **headline(30.0, 24.0, 24.6, 22.8, 0.85)},
                          {"method": "doe+wiener", **headline(29.75, 23.60, 23.83, 22.51, 0.84)}]}
    with pytest.raises(judge.JudgeError, match="doe.safetensors: its SHA-256 is not the card's"):
        judge.judge(args(repo, cand, shipped="none", ship=True), evaluate=fake_eval({"proposed,doe+wiener": better}))
    assert (repo / "models" / "dcnn.onnx").read_bytes() == b"old net"
    assert judge.LOG_HEADING not in (repo / "training.md").read_text()


def test_bad_inputs_are_clear_errors_naming_the_file(tmp_path, capsys):
    repo, cand = repo_with_candidate(tmp_path)
    with pytest.raises(SystemExit) as e:
        judge.main(["--candidate", str(repo / "missing.onnx"), "--log", "none"])
    assert e.value.code == 1
    assert "missing.onnx: not an ONNX file" in capsys.readouterr().err
    cand.with_suffix(".card.json").write_text("{not json")
    with pytest.raises(judge.JudgeError, match="dcnn-full.card.json: not a model card"):
        judge.judge(args(repo, cand), evaluate=fake_eval({}))
    cand.with_suffix(".card.json").write_text("{}")
    no_row = {"methods": [{"method": "doe+wiener", **headline(1, 1, 1, 1)}]}
    with pytest.raises(judge.JudgeError, match="no row 'proposed'"):
        judge.judge(args(repo, cand, shipped="none"), evaluate=fake_eval({"proposed,doe+wiener": no_row}))


def unrolled_candidate(tmp_path) -> Path:
    """An unrolled model's manifest (its networks are not read here)."""
    repo, _ = repo_with_candidate(tmp_path)
    path = repo / "out" / "unrolled-k3.unrolled.toml"
    path.write_text('format = "nedrt unrolled 1"\nobjective = "target"\ntrained_size = [256, 256]\n'
                    + "".join(f'\n[[step]]\nrho = {r}\nrelaxation = 1.8\n' + ('network = "n.onnx"\n' if n else "")
                              for r, n in ((0.05, True), (0.06, False), (0.07, True))))
    return repo, path


def test_an_unrolled_model_is_judged_by_its_own_rule_and_not_shipped(tmp_path):
    repo, cand = unrolled_candidate(tmp_path)
    wiener = headline(29.75, 23.60, 23.83, 22.51, 0.84)
    # +0.5 vs sharp and not below vs target (mean, worst): it passes, SSIM aside.
    good = {"methods": [{"method": "proposed", **headline(29.75, 23.70, 24.33, 22.60, 0.80)},
                        {"method": "doe+wiener", **wiener}]}
    ev = fake_eval({"proposed,doe+wiener": good})
    judge.judge(args(repo, cand, shipped="none"), evaluate=ev)
    log = (repo / "training.md").read_text()
    assert ev.calls == [("unrolled-k3.unrolled.toml", "proposed,doe+wiener")]
    assert "**passes the unrolled rule's quality lines**" in log
    assert "Manifest: 3 split-solver steps @target (2 with a learned correction), ρ/L 0.050, 0.060, 0.070" in log
    # 0.49 dB vs sharp is short; the worst depth vs target below the Wiener's fails too.
    short = {"methods": [{"method": "proposed", **headline(30.5, 23.59, 24.32, 22.60)},
                         {"method": "doe+wiener", **wiener}]}
    judge.judge(args(repo, cand, shipped="none"), evaluate=fake_eval({"proposed,doe+wiener": short}))
    log = (repo / "training.md").read_text()
    assert "mean vs sharp 24.32 dB is not 0.5 dB above its Wiener's 23.83" in log
    assert "worst vs target 23.59 dB is below its Wiener's 23.60" in log
    with pytest.raises(judge.JudgeError, match="judged, not shipped"):
        judge.judge(args(repo, cand, ship=True), evaluate=ev)
    cand.write_text("not toml [")
    with pytest.raises(judge.JudgeError, match="not an unrolled model's manifest"):
        judge.judge(args(repo, cand, shipped="none"), evaluate=ev)
