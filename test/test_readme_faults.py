"""README's "What happens when things go wrong" table is kept true by tests (issue 25).

Each row of the table is mapped here to the tests that exercise exactly that fault against
the behaviour the row claims; the registry fails when a row is added without tests, when a
mapping names a row that is no longer in the README, or when a mapped test no longer exists
(read from the test files' syntax trees: the tests themselves run in their own files).
"""

from __future__ import annotations

import ast
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HEADING = "### What happens when things go wrong"

#: the start of a row's fault cell -> the tests (``file::function``) that hold it
ROWS: dict[str, tuple[str, ...]] = {
    "Ctrl-C / SIGINT / SIGTERM": (
        "test_nodes_shutdown.py::test_run_sigint_twice_hands_back_before_context_goes",
        "test_nodes_shutdown.py::test_run_bounded_when_shutdown_never_completes",
    ),
    "controller input stale, frozen stamp": (
        "test_safety.py::test_stale_stream_boundary",
        "test_safety.py::test_future_stamp_beyond_tolerance",
        "test_safety.py::test_non_finite_value_names_index",
        "test_controller_safety.py::test_frozen_stamp_aborts",
    ),
    "controller input physically absurd": (
        "test_controller_safety.py::test_absurd_inputs_abort_the_controller",
        "test_controller_safety.py::test_plausible_inputs_near_the_bounds_fly",
    ),
    "reference step / excitation beyond the design envelope": (
        "test_controller_safety.py::test_reference_step_aborts_before_a_feedforward_spike",
        "test_controller_safety.py::test_excitation_beyond_the_design_aborts",
    ),
    "commands computed from states older than the certified loop delay": (
        "test_loop_delay_watchdog.py::test_sustained_delay_just_above_the_bound_aborts_after_the_tolerance",
        "test_loop_delay_watchdog.py::test_sustained_delay_just_below_the_bound_never_aborts",
        "test_loop_delay_watchdog.py::test_runtime_aborts_on_a_sustained_delay_just_above_the_bound",
    ),
    "gains.yaml edited after synthesis": (
        "test_phase2_one_path.py::test_every_tamper_is_refused_by_the_node_and_by_fly_phase2_alike",
        "test_phase2_one_path.py::test_chain_phase2_refuses_what_the_node_refuses",
        "test_controller_safety.py::test_tampered_gains_are_refused",
        "test_controller_safety.py::test_negated_gains_with_a_recomputed_hash_fail_the_stability_recheck",
        "test_gains_seal.py::test_any_edit_outside_the_law_is_refused_by_the_node_and_verify",
        "test_gains_seal.py::test_verify_checks_the_law_hash",
        "test_gains_seal.py::test_keyed_seal_synthesize_verify_and_node",
        "test_gains_seal.py::test_controller_node_requires_the_keyed_seal_when_given_a_key",
    ),
    "altitude floor/ceiling, geofence, tilt, speed, absurd setpoint": (
        "test_envelope.py::test_ceiling_fence_tilt_speed_with_analytic_values",
        "test_envelope.py::test_descent_toward_the_floor_is_stopped_and_control_handed_back",
        "test_envelope.py::test_huge_or_non_finite_reference_is_rejected_and_hands_back",
    ),
    "absurd actuator command": (
        "test_absurd_commands.py::test_attitude_rate_transport_clips_saturation_but_aborts_on_absurd_values",
        "test_absurd_commands.py::test_rate_setpoint_transport_aborts_on_absurd_values",
        "test_absurd_commands.py::test_bridge_aborts_on_an_absurd_command_while_offboard",
    ),
    "HEARTBEAT, COMMAND_ACK or HOME_POSITION from another component": (
        "test_mavlink_evidence.py::test_heartbeat_of_another_component_is_no_mode_evidence",
        "test_mavlink_evidence.py::test_home_position_and_ack_only_from_the_autopilot_component",
        "test_mavlink_evidence.py::test_target_system_0_refuses_when_two_autopilots_are_heard",
        "test_mavlink_evidence.py::test_explicit_target_system_ignores_a_foreign_autopilot",
    ),
    "vehicle back in OFFBOARD after the hand-back was confirmed": (
        "test_offboard_truth.py::test_vehicle_back_in_offboard_after_done_is_reported_each_time",
        "test_offboard_truth.py::test_unconfirmed_handback_still_in_offboard_is_not_a_revert",
    ),
    "PX4 rejects a hand-back mode": (
        "test_offboard_truth.py::test_posctl_handback_without_rc_ends_in_confirmed_hold_never_done_posctl",
        "test_offboard_truth.py::test_nothing_confirmed_ends_failed_loudly_and_stops_the_stream",
    ),
    "MAVLink link lost": (
        "test_mavlink_core.py::test_machine_abort_shutdown_link_loss_and_pilot_takeover",
    ),
    "no ESC telemetry": (
        "test_telemetry_hygiene.py::test_estimated_rotor_speeds_from_actuator_output_status",
        "test_rotor_estimate.py::test_recorder_writes_the_rotor_speed_source_into_experiment_yaml",
    ),
    "telemetry from another system id": (
        "test_telemetry_hygiene.py::test_decoder_accepts_only_the_target_system_and_component",
        "test_telemetry_hygiene.py::test_bridge_publishes_state_only_from_the_target_and_reports_the_rest",
    ),
    "data logger killed": (
        "test_bag_durability.py::test_kill9_at_1khz_readable_by_anyreader_after_repair",
        "test_bag_durability.py::test_logger_restart_on_killed_recording_repairs_it",
    ),
    "disk full": (
        "test_bag_durability.py::test_disk_full_bag_opens_and_metadata_claims_no_more",
        "test_bag_durability.py::test_injected_enospc_mcap_recorder_keeps_every_accepted_message",
    ),
    "malformed / hostile input file": (
        "test_hostile_inputs.py::test_hostile_yaml_file_exits_2_with_one_line",
        "test_hostile_inputs.py::test_hostile_npz_exits_2_with_one_line",
        "test_named_errors.py::test_a_topic_of_the_wrong_type_is_a_named_bag_error",
        "test_named_errors.py::test_replay_of_a_wrong_typed_bag_exits_2_not_1",
    ),
    "bag cut inside a chunk, or a byte flipped inside one": (
        "test_bag_durability.py::test_mcap_cut_anywhere_keeps_every_complete_record",
        "test_bag_durability.py::test_repair_of_one_big_chunk_cut_in_half_keeps_its_complete_messages",
        "test_bag_durability.py::test_chunks_carry_crcs_and_a_flipped_byte_is_caught_on_read",
    ),
    "node parameter file with a misspelled key": (
        "test_node_params.py::test_misspelled_key_in_a_params_file_refuses_the_node",
        "test_node_params.py::test_unknown_ros_parameter_given_with_p_is_refused_too",
    ),
    "`--out` that is an input of the run": (
        "test_outputs_over_inputs.py::test_verify_out_equal_to_the_gains_is_refused",
        "test_outputs_over_inputs.py::test_synthesize_out_equal_to_the_models_is_refused",
        "test_outputs_over_inputs.py::test_signals_out_does_not_replace_an_existing_signal_set",
    ),
    "absurd counts or steps": (
        "test_bounded_counts.py::test_signal_sample_interval_below_the_design_limit_is_refused",
        "test_bounded_counts.py::test_verify_counts_are_bounded",
        "test_bounded_counts.py::test_synthesis_gamma_is_bounded_on_every_path",
    ),
}


def readme_rows() -> list[str]:
    """The fault cell of every row of the README table."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert HEADING in text
    rows = []
    for line in text.split(HEADING, 1)[1].splitlines()[1:]:
        if not line.startswith("|"):
            if rows:
                break
            continue
        cell = line.strip("|").split(" | ")[0].strip()
        if cell not in ("fault",) and not set(cell) <= set("-| "):
            rows.append(cell)
    return rows


@lru_cache(maxsize=None)
def _functions(test_file: str) -> frozenset[str]:
    tree = ast.parse((ROOT / "test" / test_file).read_text(encoding="utf-8"))
    return frozenset(
        n.name for n in tree.body if isinstance(n, ast.FunctionDef) and n.name.startswith("test")
    )


def test_every_readme_row_is_mapped_to_tests_and_every_mapping_to_a_row():
    rows = readme_rows()
    assert len(rows) >= 20
    unmapped = [r for r in rows if not any(r.startswith(k) for k in ROWS)]
    assert unmapped == [], "README rows without tests"
    stale = [k for k in ROWS if not any(r.startswith(k) for r in rows)]
    assert stale == [], "mappings of rows no longer in the README"
    for k in ROWS:
        assert sum(r.startswith(k) for r in rows) == 1, k


@pytest.mark.parametrize("key", sorted(ROWS))
def test_every_mapped_test_exists(key):
    assert ROWS[key], key
    for ref in ROWS[key]:
        test_file, name = ref.split("::")
        assert name in _functions(test_file), ref
