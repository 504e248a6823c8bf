"""Runtime parts that need no vehicle: the flight log and the per-vehicle state board."""

from __future__ import annotations

import asyncio
import csv
import time

import pytest

from companion.app.flight_log import FLIGHT_COLUMNS, FlightLog, Track
from companion.errors import TelemetryLost
from companion.vehicle.board import VehicleBoard
from companion.vehicle.port import FlightMode


def _pose(board: VehicleBoard, t: float):
    return board.put_pose(t_sim_s=t, x_east_m=t, y_north_m=0.0, alt_rel_m=50.0, vx_east_m_s=1.0,
                          vy_north_m_s=0.0, heading_enu_rad=0.0)


def test_flight_csv_is_on_disk_within_the_flush_period(tmp_path):
    with FlightLog(tmp_path, flush_every_s=0.05) as log:
        log.row(t_mission_s=0.0, t_sim_s=10.0, vehicle="a", action="fly", x_m=1.0)
        time.sleep(0.06)
        log.row(t_mission_s=0.5, t_sim_s=10.5, vehicle="a", action="fly", x_m=6.0)
        # Still open, as during a flight: a crash now would keep both rows.
        rows = list(csv.DictReader((tmp_path / "flight.csv").read_text().splitlines()))
        assert [r["t_sim_s"] for r in rows] == ["10.000", "10.500"]
        assert list(rows[0]) == list(FLIGHT_COLUMNS)
        with pytest.raises(ValueError, match="unknown flight.csv columns"):
            log.row(t_sim=1.0)
        log.traffic(3.0, "truck", "a", 1.0, 2.0, 3.0, 4.0)
        log.traffic(3.0, "truck", "a", 1.0, 2.0, 3.0, 4.0)  # the same report seen twice
        log.traffic(3.0, "truck", "b", 1.0, 2.0, 3.0, 4.0)
    traffic = list(csv.DictReader((tmp_path / "traffic.csv").read_text().splitlines()))
    assert [(r["callsign"], r["via"]) for r in traffic] == [("truck", "a"), ("truck", "b")]


def test_track_keeps_strictly_increasing_times():
    tr = Track()
    for t, x in ((1.0, 0.0), (1.0, 5.0), (0.5, 9.0), (2.0, 10.0)):
        tr.add(t, x, 0.0)
    assert tr.t_s == [1.0, 2.0] and tr.x_m == [0.0, 10.0]


def test_board_hands_out_newer_samples_and_times_out_cleanly():
    async def scenario():
        board = VehicleBoard("a")
        with pytest.raises(TelemetryLost, match="vehicle 'a'"):
            await board.next_pose(0, 0.05)

        async def feed():
            await asyncio.sleep(0.01)
            await _pose(board, 1.0)
            await asyncio.sleep(0.01)
            await _pose(board, 1.2)
        async with asyncio.TaskGroup() as tg:
            tg.create_task(feed())
            first = await board.next_pose(0, 1.0)
            second = await board.next_pose(first.seq, 1.0)
        assert (first.t_sim_s, second.t_sim_s) == (1.0, 1.2) and second.seq > first.seq

        await board.put_status(mode=FlightMode.OFFBOARD)
        await board.wait_until(lambda s, p: s.mode is FlightMode.OFFBOARD, 0.1, "offboard")
        with pytest.raises(TelemetryLost, match="HOLD"):
            await board.wait_until(lambda s, p: s.mode is FlightMode.HOLD, 0.05, "HOLD")
    asyncio.run(scenario())


def test_board_measures_the_speed_factor_from_the_vehicle_clock():
    async def scenario():
        board = VehicleBoard("a")
        for i in range(300):  # 3 s of wall at 100 samples a second, the clock at 20x
            await board.note_clock(0.2 * i, wall_s=100.0 + 0.01 * i)
        assert board.latest_clock_s == pytest.approx(59.8)
        assert board.sim_rate == pytest.approx(20.0, rel=1e-6)
    asyncio.run(scenario())


def test_primary_error_is_the_cause_not_the_cancellations():
    from companion.errors import CommandRefused, primary_error
    cause = CommandRefused("arm", "COMMAND_DENIED", vehicle="b")
    group = BaseExceptionGroup("tg", [asyncio.CancelledError(), ExceptionGroup("inner", [cause])])
    assert primary_error(group) is cause
    assert str(cause) == "vehicle 'b': arm refused: COMMAND_DENIED"
    only_cancel = BaseExceptionGroup("tg", [asyncio.CancelledError()])
    assert isinstance(primary_error(only_cancel), asyncio.CancelledError)
