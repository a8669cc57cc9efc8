"""Shared fixtures: small, fast runs of the real pipeline."""

from __future__ import annotations

import pytest

#: Overrides for a quick run: a few hundred digits, no bars, no re-evaluation.
QUICK = [
    "dataset.train_size=600",
    "dataset.val_size=200",
    "dataset.test_size=300",
    "trainer.progress=false",
    "trainer.verify_preset=null",
    "output.examples=4",
]


@pytest.fixture
def quick():
    """Dotted overrides (``key=value``) for a quick run."""
    return list(QUICK)


@pytest.fixture
def quick_args(tmp_path):
    """CLI arguments for a quick run writing under tmp_path."""
    return [f"--{o}" for o in QUICK] + [f"--output.root={tmp_path}"]


@pytest.fixture(autouse=True)
def _no_strict_plugins(monkeypatch):
    monkeypatch.delenv("OPTOENC_STRICT_PLUGINS", raising=False)


#: End-to-end cases that run the CLI or a sweep in subprocesses for seconds each, marked ``slow`` here (by node id,
#: parametrised cases included) so that the default suite stays under four minutes on two cores. Each behaviour keeps
#: a faster sibling in the default suite (named after the arrow); ``pytest -m slow`` runs these.
SLOW_CASES = {
    "tests/sweep/test_run.py::test_sweep_isolates_failures_skips_finished_and_collects": "sweep/test_order, test_interrupt_after_training",
    "tests/sweep/test_run.py::test_a_stopped_sweep_stops_its_running_cell_and_starts_no_more[ctrl-c-to-its-group]": "[sigterm-to-the-sweep]",
    "tests/faults/test_interrupts.py::test_signal_mid_run[2-130]": "[15-143]",
    "tests/faults/test_what_a_person_sees.py::test_progress_in_a_log_is_one_line_per_epoch": "test_batch_limits_for_smoke_tests",
    "tests/faults/test_resume_contract.py::test_resume_with_safe_changes_continues": "test_training resume tests",
    "tests/faults/test_resume_contract.py::test_copied_run_keeps_its_best_checkpoint": "test_last_checkpoint_is_the_last_epoch...",
    "tests/faults/test_resume_contract.py::test_resume_with_changed_settings_is_refused_and_writes_nothing[change5-keys5]": "the other changes",
    "tests/faults/test_resume_contract.py::test_missing_or_corrupt_last_checkpoint_is_one_line_naming_the_file[truncate]": "the other corruptions",
    "tests/faults/test_resume_contract.py::test_test_with_a_different_decoder_setting_is_refused": "the changed-settings refusals",
    "tests/faults/test_filesystem.py::test_cli_run_files_and_pictures_are_readable_by_others": "test_cli_out_naming_an_existing_folder",
    "tests/faults/test_training_edges.py::test_split_sizes_refused_before_training[--dataset.val_size=0-dataset.val_size]": "the other sizes",
    "tests/faults/test_training_edges.py::test_labels_outside_the_class_count_are_a_data_error": "test_datasets' label checks",
    "tests/faults/test_nonfinite_and_sizes.py::test_cli_non_finite_loss_aborts_with_exit_1_naming_the_setting": "the library-level non-finite tests",
    "tests/faults/test_what_a_person_sees.py::test_psf_command_prints_the_mask_path_too": "test_encoder_commands' psf tests",
    "tests/test_examples.py::test_conditioning_compares_three_normalisations_of_one_fixed_embedding": "test_decoders",
    "tests/test_scale_out.py::test_mlflow_logger_uses_a_sqlite_store": "the tensorboard logger test",
    "tests/encoders/test_matrix_units.py::test_build_and_apply_backward_passes_are_the_products_adjoints[3]": "[1]",
}


def pytest_collection_modifyitems(config, items):
    import pytest

    for item in items:
        if item.nodeid in SLOW_CASES:
            item.add_marker(pytest.mark.slow)
