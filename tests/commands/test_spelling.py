"""One spelling of the options on every verb, the Lightning verbs' (simplenerf.commands): snake_case, `--ckpt_path`,
the CLI's overrides among a verb's own options. The spellings before (kebab-case, `--ckpt`, overrides after `--`) still
parse, to the same arguments, with a note on stderr; `--help` shows only the one spelling, for every verb there is and
any added later."""

from __future__ import annotations

import contextlib
import importlib
import re

import pytest

from simplenerf.commands import LIGHTNING_VERBS, VERBS, CommandParser, main, split_overrides

# Verbs whose arguments are not parsed by a CommandParser of their own: sparse-depth hands them to LightningCLI.
NOT_ARGPARSE = ("sparse-depth",)


def parsers(verb: str) -> list[CommandParser]:
    """The parsers of a verb (download: one per dataset)."""
    module = importlib.import_module(VERBS[verb].target.partition(":")[0])
    if verb == "download":
        return [module.llff_parser(), module.realestate_parser()]
    return [module.build_parser()]


# verb (download: "download <dataset>"), arguments in the one spelling, the same in the spellings before, and what
# they parse to.
CASES = [
    ("render-video", ["--config", "a.yaml", "--ckpt_path", "c.ckpt", "--depth_range", "1", "2"],
     ["--config", "a.yaml", "--ckpt", "c.ckpt", "--depth-range", "1", "2"],
     {"config": ["a.yaml"], "ckpt_path": "c.ckpt", "depth_range": [1.0, 2.0]}),
    ("export-geometry",
     ["--config", "a.yaml", "--ckpt_path", "c.ckpt", "--min_accumulation", "0.5", "--far_factor", "0"],
     ["--config", "a.yaml", "--ckpt", "c.ckpt", "--min-accumulation", "0.5", "--far-factor", "0"],
     {"ckpt_path": "c.ckpt", "min_accumulation": 0.5, "far_factor": 0.0}),
    ("export-depth", ["--config", "a.yaml", "--ckpt_path", "c.ckpt", "--out", "o"],
     ["--config", "a.yaml", "--ckpt", "c.ckpt", "--out", "o"], {"config": ["a.yaml"], "ckpt_path": "c.ckpt"}),
    ("heldout-depth", ["--config", "a.yaml", "--config", "b.yaml", "--ckpt_path", "c.ckpt"],
     ["--config", "a.yaml", "--config", "b.yaml", "--ckpt", "c.ckpt"],
     {"config": ["a.yaml", "b.yaml"], "ckpt_path": "c.ckpt"}),
    ("visibility-masks", ["--config", "a.yaml", "--min_views", "3"], ["--config", "a.yaml", "--min-views", "3"],
     {"config": ["a.yaml"], "min_views": 3}),
    ("rescore", ["runs/x", "--lpips_weights", "w.npz", "--no_lpips", "--min_views", "2"],
     ["runs/x", "--lpips-weights", "w.npz", "--no-lpips", "--min-views", "2"],
     {"run": "runs/x", "lpips_weights": "w.npz", "no_lpips": True, "min_views": 2}),
    ("results", ["A=runs/a", "--per_scene"], ["A=runs/a", "--per-scene"], {"runs": ["A=runs/a"], "per_scene": True}),
    ("synthetic", ["out", "--n_frames", "2"], ["out", "--n-frames", "2"], {"n_frames": 2}),
    ("process-data",
     ["--images", "i", "--output", "o", "--camera_model", "PINHOLE", "--max_size", "100", "--sift_max_size", "200",
      "--max_features", "50"],
     ["--images", "i", "--output", "o", "--camera-model", "PINHOLE", "--max-size", "100", "--sift-max-size", "200",
      "--max-features", "50"],
     {"camera_model": "PINHOLE", "max_size": 100, "sift_max_size": 200, "max_features": 50}),
    ("sweep", ["--config", "s.yaml", "--dry_run"], ["--config", "s.yaml", "--dry-run"], {"dry_run": True}),
    ("download llff", ["--remove_archive", "--dry_run"], ["--remove-archive", "--dry-run"],
     {"remove_archive": True, "dry_run": True}),
    ("download realestate", ["--metadata_sha256", "ab", "--keep_videos", "--dry_run"],
     ["--metadata-sha256", "ab", "--keep-videos", "--dry-run"],
     {"metadata_sha256": "ab", "keep_videos": True, "dry_run": True}),
    # verbs with no option renamed: the one spelling parses
    ("run-history", ["runs/x", "--keys", "train/.*"], ["runs/x", "--keys", "train/.*"], {"keys": "train/.*"}),
    ("view", ["runs/x", "--port", "0"], ["runs/x", "--port", "0"], {"run": "runs/x", "port": 0}),
    ("benchmark", ["--config", "a.yaml", "--steps", "1"], ["--config", "a.yaml", "--steps", "1"],
     {"config": ["a.yaml"], "steps": 1}),
]


def case_parser(name: str) -> CommandParser:
    verb, _, dataset = name.partition(" ")
    return parsers(verb)[["llff", "realestate"].index(dataset)] if dataset else parsers(verb)[0]


def test_every_verb_has_a_case():
    assert {name.split()[0] for name, *_ in CASES} == set(VERBS) - set(LIGHTNING_VERBS) - set(NOT_ARGPARSE)


@pytest.mark.parametrize(("name", "new", "old", "expected"), CASES, ids=[c[0] for c in CASES])
def test_the_one_spelling_and_the_one_before_parse_alike(name, new, old, expected, capsys):
    args = case_parser(name).parse_args(new)
    assert capsys.readouterr().err == ""  # the one spelling: no note
    assert {k: getattr(args, k) for k in expected} == expected
    assert case_parser(name).parse_args(old) == args
    assert capsys.readouterr().err.splitlines() == [
        f"simplenerf {name}: note: {a} is spelled {b} now (as on every verb)"
        for a, b in zip(old, new, strict=True) if a != b]


def test_a_spelling_before_is_noted_once_and_read_with_an_equals_sign(capsys):
    parser = case_parser("visibility-masks")
    args = parser.parse_args(["--config", "a.yaml", "--min-views=2", "--min-views", "4"])
    assert args.min_views == 4
    assert capsys.readouterr().err == "simplenerf visibility-masks: note: --min-views is spelled --min_views now (as " \
                                      "on every verb)\n"


def test_a_missing_required_option_is_named_in_the_one_spelling(capsys):
    with pytest.raises(SystemExit) as done:
        case_parser("render-video").parse_args(["--config", "a.yaml"])
    assert done.value.code == 2
    assert capsys.readouterr().err.splitlines() == [
        "simplenerf: error: the following arguments are required: --ckpt_path",
        "hint: `simplenerf render-video --help` lists every option"]


def test_a_kebab_case_option_cannot_be_added():
    parser = CommandParser("new-verb", None)
    with pytest.raises(ValueError, match=r"^simplenerf new-verb: option --out-dir: spell it --out_dir \(the "):
        parser.add_argument("--out-dir")
    parser.add_argument("--out_dir")  # its kebab-case spelling is then read as it, like every option's
    assert parser.parse_args(["--out-dir", "x"]).out_dir == "x"


def help_of(argv: list[str]) -> str:
    """What `simplenerf <argv> --help` prints: its usage and option lines (not the examples of its description)."""
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        main([*argv, "--help"])
    text = out.getvalue()
    usage, _, rest = text.partition("\n\n")
    return "\n".join([usage, *(line for line in rest.splitlines() if line.lstrip().startswith("-"))])


HELPS = [[v] for v in VERBS if v not in LIGHTNING_VERBS] + [["download", "llff"], ["download", "realestate"]]


@pytest.mark.parametrize("argv", HELPS, ids=[" ".join(a) for a in HELPS])
def test_no_verb_shows_a_kebab_case_option_or_ckpt(argv):
    """The Lightning verbs' spelling on every other verb, present and future (a verb added to VERBS is checked)."""
    text = help_of(argv)
    options = re.findall(r"(?<![\w-])--[A-Za-z][\w.-]*", text)
    assert options or argv[0] in NOT_ARGPARSE + ("download",)
    assert [o for o in options if "-" in o[2:] or o == "--ckpt"] == []


def test_the_helps_checked_show_the_renamed_options():
    """The check above is not vacuous: it reads the option lines, where the renamed options are."""
    assert "--ckpt_path CKPT_PATH" in help_of(["render-video"]) and "--dry_run" in help_of(["download", "llff"])


@pytest.mark.parametrize(("argv", "own", "overrides"), [
    # the overrides among the verb's own options, each with its value
    (["runs/x", "--port", "8081", "--data.init_args.scene_dir", "d", "--trainer.max_steps=5", "--seed_everything", "1",
      "--model", "pkg.Model"],
     ["runs/x", "--port", "8081"],
     ["--data.init_args.scene_dir", "d", "--trainer.max_steps=5", "--seed_everything", "1", "--model", "pkg.Model"]),
    # a positional after an override's value stays the verb's; a negative value is a value
    (["--data.init_args.scene_dir", "d", "--model.x", "-1", "runs/x"], ["runs/x"],
     ["--data.init_args.scene_dir", "d", "--model.x", "-1"]),
    # an override followed by an option has no value
    (["--trainer.fast_dev_run", "--out", "o"], ["--out", "o"], ["--trainer.fast_dev_run"]),
    # after `--` (the spelling before), everything; both may be mixed, the direct ones first
    (["--config", "a.yaml", "--", "--config", "b.yaml", "--data.x", "1"], ["--config", "a.yaml"],
     ["--config", "b.yaml", "--data.x", "1"]),
    (["--model.y", "2", "--ckpt_path", "c", "--", "--data.x", "1"], ["--ckpt_path", "c"],
     ["--model.y", "2", "--data.x", "1"]),
    # the verb's own options are not overrides, neither is an option of neither (argparse refuses it)
    (["--config", "a.yaml", "--ckpt_path", "c", "--min_views", "3", "--lpips", "x"],
     ["--config", "a.yaml", "--ckpt_path", "c", "--min_views", "3", "--lpips", "x"], []),
])
def test_split_overrides(argv, own, overrides):
    assert split_overrides(argv) == (own, overrides)


def test_a_verb_without_overrides_refuses_one_with_one_line(capsys):
    with pytest.raises(SystemExit) as done:
        main(["results", "A=runs/a", "--data.init_args.scene_dir", "d"])
    assert done.value.code == 2
    assert capsys.readouterr().err.splitlines() == [
        "simplenerf: error: unrecognized arguments: --data.init_args.scene_dir d",
        "hint: `simplenerf results --help` lists every option"]


def test_a_spelling_before_after_a_double_dash_is_left_to_the_cli():
    assert case_parser("render-video").respelled(["--ckpt", "c", "--", "--ckpt", "x"]) == [
        "--ckpt_path", "c", "--", "--ckpt", "x"]
