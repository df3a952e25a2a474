"""Config tree: profiles, --config files, --set overrides and one-line errors."""

from pathlib import Path

import pytest

from components.errors import MultigraspError
from flows.config import available_profiles, load_config, section_digest


def test_profiles_smoke_mini_bench_paper_load():
    assert {"smoke", "mini", "bench", "paper"} <= set(available_profiles())
    for profile in ("smoke", "mini", "bench", "paper"):
        cfg = load_config(profile)
        assert cfg.profile == profile
        assert cfg.run.workdir.is_absolute()


def test_the_paper_profile_has_the_papers_lifting_budget_and_evaluation_size():
    """The paper's text: 8000 PPO iterations of 512 environments per policy, 512 evaluation poses x 5 trials (until
    the fifty-first session the profile left PPO and the evaluation at the defaults, 50 x 2000 frames and 100)."""
    specialists = load_config("paper").specialists
    assert specialists.ppo.iterations == 8000 and specialists.ppo.frames_per_batch == 512 * 16
    assert (specialists.eval_poses, specialists.eval_trials) == (512, 5) and specialists.init_policy == "zero"


def test_bench_pairs_choose_no_palm_contacts_while_singles_and_many_objects_keep_them():
    synthesis = load_config("bench").synthesis
    assert synthesis.optimizer_for(2).contact_regions_excluded == ["palm", "palm_hypothenar"]
    for count in (1, 3, 4, 5):
        assert synthesis.optimizer_for(count).contact_regions_excluded == []


def test_set_overrides_are_yaml_parsed(tmp_path):
    cfg = load_config("smoke", sets=["run.seed=7", "scenes.per_combination.train=3", "run.runner=processes"],
                      workdir=tmp_path)
    assert cfg.run.seed == 7 and cfg.scenes.per_combination.train == 3 and cfg.run.runner == "processes"
    assert cfg.run.workdir == tmp_path.resolve()


def test_config_file_is_merged_over_profile(tmp_path):
    extra = tmp_path / "mine.yaml"
    extra.write_text("scenes:\n  renders: 1\nrun:\n  seed: 5\n")
    cfg = load_config("smoke", config_file=extra)
    assert cfg.scenes.renders == 1 and cfg.run.seed == 5
    assert cfg.scenes.per_combination.train == load_config("smoke").scenes.per_combination.train


def _one_line_error(**kwargs) -> str:
    with pytest.raises(MultigraspError) as info:
        load_config(**kwargs)
    message = str(info.value)
    assert "\n" not in message and len(message) < 300
    return message


def test_unknown_config_key_names_the_key_and_suggests_a_fix():
    message = _one_line_error(profile="smoke", sets=["scenes.render=3"])
    assert "unknown config key 'scenes.render'" in message and "scenes.renders" in message


def test_a_misspelt_field_of_a_user_mesh_is_suggested_with_its_index():
    """A typo inside a list item (a user mesh's ``scael``) was answered with the list (``objects.user``)."""
    meshes = "[{name: a, mesh: a.obj}, {name: b, mesh: b.obj, scael: 0.8}]"
    message = _one_line_error(profile="smoke", sets=[f"objects.user={meshes}"])
    assert "unknown config key 'objects.user.1.scael' (did you mean 'objects.user.1.scale'?)" in message


def test_a_missing_required_key_is_named_with_the_unknown_key_given_in_its_place():
    """A user mesh written with ``path`` instead of ``mesh`` was answered "bad value for 'objects.user.0.mesh':
    Field required (got a mapping)"."""
    message = _one_line_error(profile="smoke", sets=["objects.user=[{name: mug, path: mug.obj}]"])
    assert message == ("missing config key 'objects.user.0.mesh' (required); 'objects.user.0.path' is not a key there "
                       "(did you mean 'mesh'?) — `multigrasp config --describe` lists every key")
    message = _one_line_error(profile="smoke", sets=["objects.user=[{mesh: mug.obj}]"])
    assert message.startswith("missing config key 'objects.user.0.name' (required) — ")


def test_out_of_range_value_names_the_key():
    message = _one_line_error(profile="smoke", sets=["scenes.renders=-1"])
    assert "scenes.renders" in message and "greater than or equal to 0" in message
    # the value is shown even where its digits occur in pydantic's message (16 holds 1)
    message = _one_line_error(profile="smoke", sets=["objects.surface_points=1"])
    assert "greater than or equal to 16 (got 1)" in message


def test_bad_choice_names_the_key():
    message = _one_line_error(profile="smoke", sets=["run.runner=gpu"])
    assert "run.runner" in message


def test_unknown_profile_lists_the_profiles():
    message = _one_line_error(profile="fast")
    assert "unknown profile 'fast'" in message and "smoke" in message


def test_missing_or_invalid_config_file(tmp_path):
    assert "not found" in _one_line_error(profile="smoke", config_file=tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("scenes: [unclosed\n")
    assert "not valid YAML" in _one_line_error(profile="smoke", config_file=bad)


def test_set_without_equals_sign():
    assert "KEY=VALUE" in _one_line_error(profile="smoke", sets=["run.seed"])


def test_section_digest_changes_only_with_its_section():
    a = load_config("smoke")
    b = load_config("smoke", sets=["run.seed=1"])
    c = load_config("smoke", sets=["scenes.renders=2"])
    assert section_digest(a, "objects") == section_digest(b, "objects")
    assert section_digest(a, "run.seed") != section_digest(b, "run.seed")
    assert section_digest(a, "scenes.sampling") == section_digest(c, "scenes.sampling")


def test_config_is_frozen():
    cfg = load_config("smoke")
    with pytest.raises(Exception):
        cfg.run.seed = 3  # type: ignore[misc]
    assert isinstance(cfg.run.workdir, Path)


def test_include_merges_listed_files_in_order_under_the_file_itself(tmp_path):
    (tmp_path / "shared").mkdir()
    (tmp_path / "shared" / "a.yaml").write_text("include: [b.yaml]\nscenes:\n  renders: 2\n  jobs_per_shard: 3\n")
    (tmp_path / "shared" / "b.yaml").write_text("scenes:\n  renders: 1\nrun:\n  seed: 4\n")
    mine = tmp_path / "mine.yaml"
    mine.write_text("include: shared/a.yaml\nscenes:\n  jobs_per_shard: 5\n")
    cfg = load_config("smoke", config_file=mine)
    # b under a (a's renders wins), a under the file (its jobs_per_shard wins), everything over the profile
    assert (cfg.scenes.renders, cfg.scenes.jobs_per_shard, cfg.run.seed) == (2, 5, 4)
    assert cfg.scenes.per_combination.train == load_config("smoke").scenes.per_combination.train


def test_include_errors_are_one_line(tmp_path):
    missing = tmp_path / "missing.yaml"
    missing.write_text("include: [nowhere.yaml]\n")
    assert "includes 'nowhere.yaml', which is not a file" in _one_line_error(profile="smoke", config_file=missing)
    loop = tmp_path / "loop.yaml"
    loop.write_text("include: [loop.yaml]\n")
    assert "makes a cycle" in _one_line_error(profile="smoke", config_file=loop)
    bad = tmp_path / "bad.yaml"
    bad.write_text("include: {a: 1}\n")
    assert "must be a file name or a list of file names" in _one_line_error(profile="smoke", config_file=bad)


def test_bench_and_paper_profiles_share_the_multi_object_setting():
    """Both include configs/shared/multi_object.yaml: the paper profile runs the bench setting longer and wider, and
    differs from it only in batch size and step counts."""
    bench, paper = load_config("bench"), load_config("paper")
    scale = {"batch_size", "approach_steps", "mala_steps", "refine_steps"}
    assert bench.scenes.sampling == paper.scenes.sampling
    for count in (1, 2, 3, 4, 5):
        b = bench.synthesis.optimizer_for(count).model_dump(exclude=scale)
        p = paper.synthesis.optimizer_for(count).model_dump(exclude=scale)
        assert b == p, {k: (b[k], p[k]) for k in b if b[k] != p[k]}
    assert paper.synthesis.optimizer.batch_size > bench.synthesis.optimizer.batch_size
    assert paper.synthesis.optimizer_for(5).fc_mode == "group"


def test_the_objects_digest_follows_the_contents_of_the_files_the_config_names(tmp_path):
    """User meshes and a custom library (its YAML and the meshes it names, relative to it) are part of the keys of
    the stages that use the objects: a file edited in place keys new units."""
    import trimesh

    (tmp_path / "meshes").mkdir()
    part, mug = tmp_path / "meshes" / "part.obj", tmp_path / "mug.obj"
    trimesh.creation.box(extents=(0.04, 0.03, 0.02)).export(part)
    trimesh.creation.box(extents=(0.03, 0.03, 0.03)).export(mug)
    library = tmp_path / "library.yaml"
    library.write_text("version: 1\nobjects:\n  part:\n    role: train\n"
                       "    shape: {type: mesh, source: meshes/part.obj}\n")
    plain = load_config("smoke", sets=[], workdir=tmp_path)
    cfg = load_config("smoke", sets=[f"objects.library_file={library}", f"objects.user=[{{name: mug, mesh: {mug}}}]",
                                     "objects.ood=[mug]"], workdir=tmp_path)

    def digests():
        return section_digest(cfg, "objects"), section_digest(cfg, "scenes"), section_digest(plain, "objects")

    first = digests()
    trimesh.creation.box(extents=(0.05, 0.03, 0.02)).export(part)  # a library mesh edited in place
    second = digests()
    trimesh.creation.box(extents=(0.03, 0.03, 0.04)).export(mug)  # a user mesh edited in place
    third = digests()
    assert len({first[0], second[0], third[0]}) == 3
    assert first[1:] == second[1:] == third[1:]  # sections without objects, and configs naming no files, keep theirs


def test_mesh_paths_in_a_config_file_are_relative_to_the_file_from_any_working_directory(tmp_path, monkeypatch):
    """A config shipped beside its meshes works wherever it is run from: its relative ``objects.user`` meshes and
    ``objects.library_file`` are read from its folder (an included file's from the included file's), made absolute
    on load; ``--set`` paths are read from the working directory."""
    import trimesh

    from components.objects.library import ObjectLibrary

    project, shared, elsewhere = tmp_path / "project", tmp_path / "project" / "shared", tmp_path / "elsewhere"
    (project / "meshes").mkdir(parents=True)
    shared.mkdir()
    elsewhere.mkdir()
    trimesh.creation.box(extents=(0.03, 0.03, 0.04)).export(project / "meshes" / "mug.obj")
    trimesh.creation.box(extents=(0.02, 0.02, 0.05)).export(shared / "part.obj")
    (shared / "library.yaml").write_text("version: 1\nobjects:\n  block:\n    role: train\n"
                                         "    shape: {type: box, size_m: [0.03, 0.03, 0.03]}\n")
    (shared / "parts.yaml").write_text("objects:\n  library_file: library.yaml\n"
                                       "  user:\n    - {name: part, mesh: part.obj}\n")
    mine = project / "mine.yaml"
    mine.write_text("include: [shared/parts.yaml]\nobjects:\n  train: [block, mug]\n  ood: [part]\n  many_object: block\n"
                    "  user:\n    - {name: part, mesh: shared/part.obj}\n    - {name: mug, mesh: meshes/mug.obj}\n")
    monkeypatch.chdir(elsewhere)
    cfg = load_config("smoke", config_file=mine, workdir=tmp_path / "runs")
    assert cfg.objects.library_file == (shared / "library.yaml").resolve()
    assert [u.mesh for u in cfg.objects.user] == [(shared / "part.obj").resolve(), (project / "meshes" / "mug.obj").resolve()]
    library = ObjectLibrary(cfg.objects, tmp_path / "cache")
    assert library.get("mug").mesh.extents.max() == pytest.approx(0.04)

    included = load_config("smoke", config_file=shared / "parts.yaml")  # relative to the included file itself
    assert included.objects.user[0].mesh == (shared / "part.obj").resolve()

    monkeypatch.chdir(project)
    on_the_command_line = load_config("smoke", sets=["objects.user=[{name: mug, mesh: meshes/mug.obj}]"])
    assert on_the_command_line.objects.user[0].mesh == (project / "meshes" / "mug.obj").resolve()


def test_a_mesh_path_found_only_from_the_working_directory_still_loads_with_a_warning(tmp_path, monkeypatch, caplog):
    """Until the fiftieth session a config file's relative mesh paths were read from the working directory: such a
    config keeps working, with a warning saying how to write the path now; a path found nowhere is made absolute
    from the file's folder, so the library's one-line error names where it was looked for."""
    import logging

    import trimesh

    (tmp_path / "configs").mkdir()
    trimesh.creation.box(extents=(0.03, 0.03, 0.04)).export(tmp_path / "mug.obj")
    mine = tmp_path / "configs" / "mine.yaml"
    mine.write_text("objects:\n  user:\n    - {name: mug, mesh: mug.obj}\n    - {name: cup, mesh: cup.obj}\n")
    monkeypatch.chdir(tmp_path)
    with caplog.at_level(logging.WARNING, logger="multigrasp"):
        cfg = load_config("smoke", config_file=Path("configs/mine.yaml"))
    assert cfg.objects.user[0].mesh == (tmp_path / "mug.obj").resolve()
    assert cfg.objects.user[1].mesh == (tmp_path / "configs" / "cup.obj").resolve()
    warning, = [r.getMessage() for r in caplog.records if "working directory" in r.getMessage()]
    assert "mug.obj" in warning and "relative to the file or absolute" in warning


def test_a_user_mesh_no_split_uses_keeps_every_stage_key(tmp_path):
    """A mesh added to ``objects.user`` alone (to ``generate`` grasps for it with the trained pipeline) changes no
    stage key and no evaluation key; listed in a split, it counts, contents included."""
    import trimesh

    from flows.config import evaluation_key

    mug = tmp_path / "mug.obj"
    trimesh.creation.box(extents=(0.03, 0.03, 0.03)).export(mug)
    plain = load_config("smoke", workdir=tmp_path)
    added = load_config("smoke", sets=[f"objects.user=[{{name: mug, mesh: {mug}}}]"], workdir=tmp_path)
    used = load_config("smoke", sets=[f"objects.user=[{{name: mug, mesh: {mug}}}]", "objects.ood=[duck, mug]"],
                       workdir=tmp_path)
    for sections in (("objects",), ("hand", "objects", "synthesis.metrics")):
        assert section_digest(added, *sections) == section_digest(plain, *sections)
    assert evaluation_key(added, "execution.json") == evaluation_key(plain, "execution.json")
    from tasks.generator import training_data_digest  # what a longer training continues from, per stage
    from tasks.specialists import training_digest

    for cfg in (plain, added):
        assert cfg.objects.used_only().user == []
    assert training_digest(added.specialists, added.lift, added.objects, added.hand) == \
        training_digest(plain.specialists, plain.lift, plain.objects, plain.hand)
    assert training_data_digest(added.generator, added.objects, added.hand) == \
        training_data_digest(plain.generator, plain.objects, plain.hand)
    assert used.objects.used_only() is used.objects  # every user mesh used: the same section, the same keys
    assert section_digest(used, "objects") != section_digest(plain.model_copy(update={"objects": plain.objects.model_copy(
        update={"ood": ["duck", "mug"]})}), "objects")  # the mesh itself counts once a split uses it


def test_the_objects_digest_follows_contents_not_where_the_files_lie(tmp_path):
    """The same config and meshes in another folder (another machine's mount of a work dir, a moved project) keep
    their keys; other contents do not."""
    import shutil

    import trimesh

    first, second = tmp_path / "here", tmp_path / "there"
    (first / "meshes").mkdir(parents=True)
    trimesh.creation.box(extents=(0.03, 0.03, 0.04)).export(first / "meshes" / "mug.obj")
    (first / "library.yaml").write_text("version: 1\nobjects:\n  part:\n    role: train\n"
                                        "    shape: {type: mesh, source: meshes/mug.obj}\n")
    (first / "my.yaml").write_text("objects:\n  library_file: library.yaml\n  train: [part]\n  ood: [mug]\n"
                                   "  many_object: part\n  user:\n    - {name: mug, mesh: meshes/mug.obj}\n")
    shutil.copytree(first, second)
    keys = [section_digest(load_config("smoke", config_file=folder / "my.yaml", workdir=tmp_path), "objects")
            for folder in (first, second)]
    assert keys[0] == keys[1]
    trimesh.creation.box(extents=(0.03, 0.03, 0.05)).export(second / "meshes" / "mug.obj")
    assert section_digest(load_config("smoke", config_file=second / "my.yaml", workdir=tmp_path), "objects") != keys[0]


def test_the_bench_specialists_train_pair_bins_only_as_the_evaluation_lifts_pairs(tmp_path):
    """With max_bins 4 the largest bins were single objects, and evaluate execution's dual-object pre-grasps matched
    no specialist: the bench profile keeps pair pre-grasps only (specialists.min_objects 2)."""
    import pandas as pd

    from tasks.grasp_tables import grasp_rows

    stage = load_config("bench").specialists
    assert (stage.min_objects, stage.max_objects) == (2, 2)
    from components.errors import MultigraspError

    with pytest.raises(MultigraspError, match="min_objects .3. exceeds max_objects"):
        load_config("bench", sets=["specialists.min_objects=3"])

    class Table:
        def path(self, name):
            return self.file

    table = Table()
    table.file = tmp_path / "grasps.parquet"
    pd.DataFrame({"split": ["train"] * 3, "object_names": [["cube"], ["cube", "bar"], ["a", "b", "c"]],
                  "scene_id": ["s1", "s2", "s3"], "row": [0, 0, 0], "accepted": [True] * 3}).to_parquet(table.file)
    assert list(grasp_rows(table, "accepted", 1, ["train"], 2, 2)["scene_id"]) == ["s2"]
    assert list(grasp_rows(table, "accepted", 1, ["train"], 2)["scene_id"]) == ["s1", "s2"]


@pytest.mark.parametrize("name", ["my/mug", "cube+mug", "mug:2", "mug,cup", "..", ""])
def test_an_object_name_that_would_break_folders_or_combinations_is_one_line_naming_the_rule(name):
    """A name names cache files and folders and is joined with '+' (combinations), ':' (scene ids) and ','
    (`generate --objects`): 'my/mug' wrote its cache into a subfolder and would have split a combination."""
    message = _one_line_error(profile="smoke", sets=[f"objects.user=[{{name: '{name}', mesh: mug.obj}}]"])
    assert "objects.user.0.name" in message
    assert name == "" or ("letters, digits, '_', '-' and '.'" in message and "rename it" in message)


def test_a_library_file_with_an_unsafe_object_name_is_one_line(tmp_path):
    from flows.config import object_name_problem

    library = tmp_path / "library.yaml"
    library.write_text("version: 1\nobjects:\n  'big+block':\n    role: train\n"
                       "    shape: {type: box, size_m: [0.03, 0.03, 0.03]}\n")
    message = _one_line_error(profile="smoke", sets=[f"objects.library_file={library}"])
    assert "big+block" in message and "rename it, e.g. 'big_block'" in message
    assert object_name_problem("mug_v2.1") is None  # dots, digits, '_' and '-' stay allowed


@pytest.mark.parametrize("profile", ["smoke", "mini", "bench", "paper"])
@pytest.mark.parametrize("describe", [False, True])
def test_config_command_prints_yaml_that_reads_back_into_the_same_config(tmp_path, capsys, profile, describe):
    """`multigrasp config --profile P > my.yaml` starts a file of one's own: read back with --config it is P's
    config, key for key (the paper profile's too, on a machine without CUDA)."""
    from flows.cli import main

    assert main(["config", "--profile", profile, *(["--describe"] if describe else [])]) == 0
    text = capsys.readouterr().out
    assert ("# Candidate grasps optimised in parallel for one scene" in text) == describe
    dumped = tmp_path / "my.yaml"
    dumped.write_text(text)
    assert load_config(None, dumped) == load_config(profile)


def test_config_command_prints_one_key_with_the_overrides_applied(tmp_path, capsys):
    import yaml

    from flows.cli import main

    sets = ["--set", "synthesis.optimizer.fc_friction=0.2", "--set", "objects.train=[cube, sphere]"]
    assert main(["config", "--profile", "bench", *sets, "--key", "synthesis.optimizer.fc_friction"]) == 0
    assert yaml.safe_load(capsys.readouterr().out) == {"synthesis": {"optimizer": {"fc_friction": 0.2}}}
    assert main(["config", "--profile", "bench", *sets, "--key", "objects.train"]) == 0
    assert yaml.safe_load(capsys.readouterr().out) == {"objects": {"train": ["cube", "sphere"]}}
    assert main(["config", "--profile", "bench", "--key", "specialists.ppo", "--describe"]) == 0
    part = capsys.readouterr().out
    assert part.startswith("specialists:\n  ppo:\n") and "# Adam learning rate" in part
    assert yaml.safe_load(part)["specialists"]["ppo"] == load_config("bench").specialists.ppo.model_dump(mode="json")


def test_config_command_with_an_unknown_key_is_one_line_naming_the_nearest(capsys):
    from flows.cli import main

    assert main(["config", "--key", "synthesis.optimiser"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown config key 'synthesis.optimiser'" in err
    assert "did you mean 'synthesis.optimizer'?" in err


def test_a_printed_config_means_the_same_from_another_folder(tmp_path, capsys, monkeypatch):
    """The work dir under the folder it was printed in is written relative (``./runs`` wherever the command runs, as
    the default means it), a user mesh by its absolute path: read back from elsewhere, it is that folder's config."""
    import trimesh

    from flows.cli import main

    first, second = tmp_path / "first", tmp_path / "second"
    (first / "meshes").mkdir(parents=True)
    second.mkdir()
    trimesh.creation.cylinder(radius=0.03, height=0.08).export(first / "meshes" / "cup.stl")
    (first / "my.yaml").write_text("objects:\n  user:\n    - {name: cup, mesh: meshes/cup.stl}\n")
    monkeypatch.chdir(first)
    assert main(["config", "--config", "my.yaml", "--set", "run.seed=4"]) == 0
    (tmp_path / "printed.yaml").write_text(capsys.readouterr().out)
    monkeypatch.chdir(second)
    expected = load_config("smoke", first / "my.yaml", ["run.seed=4"])
    read_back = load_config("smoke", tmp_path / "printed.yaml")
    assert read_back == expected and read_back.run.workdir == second / "runs"
    assert read_back.objects.user[0].mesh == first / "meshes" / "cup.stl"
