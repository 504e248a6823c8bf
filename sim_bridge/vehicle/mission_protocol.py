"""The MAVLink mission protocol, vehicle side (upload, download, clear). Pure, no sockets.

Follows PX4's ``MavlinkMissionManager``: one upload at a time; the vehicle drives an upload by
requesting item after item (MISSION_REQUEST_INT) and re-requests after
``retry_timeout_s`` of wall time, giving up after ``transfer_timeout_s`` without progress;
download answers whatever item is asked for. Missions, geofences and rally points are stored
separately (``mission_type``). Bad input ends a transfer with the matching MISSION_ACK code and
leaves the stored plan unchanged: a plan is replaced only when a whole upload has arrived.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, replace
from typing import Any, Hashable, NamedTuple

from pymavlink.dialects.v20 import common as mavlink

MISSION = mavlink.MAV_MISSION_TYPE_MISSION
FENCE = mavlink.MAV_MISSION_TYPE_FENCE
RALLY = mavlink.MAV_MISSION_TYPE_RALLY
ALL_TYPES = mavlink.MAV_MISSION_TYPE_ALL

# Storage limits (PX4's dataman sizes are of this order).
MAX_ITEMS = {MISSION: 1000, FENCE: 256, RALLY: 32}

GLOBAL_FRAMES = frozenset({
    mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_INT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
})
RELATIVE_ALT_FRAMES = frozenset({mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})

# Mission commands with a position the stub flies to.
NAV_POSITION_COMMANDS = frozenset({
    mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_UNLIM, mavlink.MAV_CMD_NAV_LOITER_TIME,
    mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_CMD_NAV_TAKEOFF,
})
# Commands accepted in a mission and executed as "done at once" (camera, gimbal, delays the
# kinematic stub has nothing to do for). MAVSDK inserts some of these itself.
NOOP_COMMANDS = frozenset({
    mavlink.MAV_CMD_DO_CHANGE_SPEED,  # executed: changes the cruise speed
    mavlink.MAV_CMD_NAV_DELAY, mavlink.MAV_CMD_CONDITION_DELAY, mavlink.MAV_CMD_CONDITION_YAW,
    mavlink.MAV_CMD_DO_DIGICAM_CONTROL, mavlink.MAV_CMD_DO_MOUNT_CONFIGURE, mavlink.MAV_CMD_DO_MOUNT_CONTROL,
    mavlink.MAV_CMD_DO_SET_CAM_TRIGG_DIST, mavlink.MAV_CMD_SET_CAMERA_MODE, mavlink.MAV_CMD_SET_CAMERA_ZOOM,
    mavlink.MAV_CMD_SET_CAMERA_FOCUS, mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
    mavlink.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, mavlink.MAV_CMD_IMAGE_START_CAPTURE,
    mavlink.MAV_CMD_IMAGE_STOP_CAPTURE, mavlink.MAV_CMD_VIDEO_START_CAPTURE, mavlink.MAV_CMD_VIDEO_STOP_CAPTURE,
})
MISSION_COMMANDS = NAV_POSITION_COMMANDS | NOOP_COMMANDS | {mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH}
FENCE_COMMANDS = frozenset({
    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
    mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
    mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT,
})
RALLY_COMMANDS = frozenset({mavlink.MAV_CMD_NAV_RALLY_POINT})
COMMANDS_BY_TYPE = {MISSION: MISSION_COMMANDS, FENCE: FENCE_COMMANDS, RALLY: RALLY_COMMANDS}


@dataclass(frozen=True, slots=True)
class MissionItem:
    """One stored item, exactly as MISSION_ITEM_INT carries it (x, y: degE7 in global frames)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int = MISSION

    @property
    def lat_deg(self) -> float:
        return self.x * 1e-7

    @property
    def lon_deg(self) -> float:
        return self.y * 1e-7

    @property
    def has_position(self) -> bool:
        return self.command in NAV_POSITION_COMMANDS and self.frame in GLOBAL_FRAMES


class ProtocolEvent(NamedTuple):
    """Something the vehicle must react to: a plan of ``mission_type`` was replaced or cleared."""

    kind: str  # "replaced" | "cleared"
    mission_type: int


class Reply(NamedTuple):
    msg: Any
    link: str
    peer: Hashable


@dataclass
class _Upload:
    mission_type: int
    count: int
    partner: tuple[int, int]
    link: str
    peer: Hashable
    items: list[MissionItem]
    started_wall: float
    last_progress_wall: float
    last_request_wall: float

    @property
    def next_seq(self) -> int:
        return len(self.items)


def validate_item(item: MissionItem) -> int:
    """MAV_MISSION_RESULT for one item: ACCEPTED or the reason it cannot be stored."""
    allowed = COMMANDS_BY_TYPE.get(item.mission_type)
    if allowed is None:
        return mavlink.MAV_MISSION_UNSUPPORTED
    if item.command not in allowed:
        return mavlink.MAV_MISSION_UNSUPPORTED
    # Fence and rally items are all positions; mission items only the NAV ones.
    needs_position = item.mission_type != MISSION or item.command in NAV_POSITION_COMMANDS
    if needs_position:
        if item.frame not in GLOBAL_FRAMES:
            return mavlink.MAV_MISSION_UNSUPPORTED_FRAME
        if not -900_000_000 <= item.x <= 900_000_000:
            return mavlink.MAV_MISSION_INVALID_PARAM5_X
        if not -1_800_000_000 <= item.y <= 1_800_000_000:
            return mavlink.MAV_MISSION_INVALID_PARAM6_Y
        if not math.isfinite(item.z):
            return mavlink.MAV_MISSION_INVALID_PARAM7
    if item.command in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_TIME):
        if not (math.isfinite(item.param1) and item.param1 >= 0.0):
            return mavlink.MAV_MISSION_INVALID_PARAM1  # hold / loiter time, s
    if item.command == mavlink.MAV_CMD_DO_CHANGE_SPEED and not math.isfinite(item.param2):
        return mavlink.MAV_MISSION_INVALID_PARAM2
    if item.mission_type == FENCE and item.command in (mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
                                                       mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION):
        if not (math.isfinite(item.param1) and item.param1 >= 0.0):
            return mavlink.MAV_MISSION_INVALID_PARAM1  # radius; PX4 stores 0 (MAVSDK's geofence example sends it)
    if item.mission_type == FENCE and item.command in (mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                                                       mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION):
        if not (math.isfinite(item.param1) and item.param1 >= 3.0):
            return mavlink.MAV_MISSION_INVALID_PARAM1  # vertex count: PX4 refuses polygons of < 3 vertices
    return mavlink.MAV_MISSION_ACCEPTED


class MissionProtocol:
    """Vehicle-side mission transfers for one vehicle."""

    def __init__(self, system_id: int, component_id: int, codec: Any, *,
                 retry_timeout_s: float = 0.25, transfer_timeout_s: float = 5.0):
        self._sysid = system_id
        self._compid = component_id
        self._mav = codec  # a pymavlink MAVLink object, used only to build messages
        self._retry_s = retry_timeout_s
        self._timeout_s = transfer_timeout_s
        self._plans: dict[int, tuple[MissionItem, ...]] = {MISSION: (), FENCE: (), RALLY: ()}
        self._upload: _Upload | None = None
        self._last_done: tuple[tuple[int, int], int, int] | None = None  # partner, type, count
        self.current_seq = 0  # the mission item being flown, for the `current` flag on download
        self.counters: Counter[str] = Counter()

    # -- queries ---------------------------------------------------------------------------
    def plan(self, mission_type: int = MISSION) -> tuple[MissionItem, ...]:
        return self._plans.get(mission_type, ())

    @property
    def upload_active(self) -> bool:
        return self._upload is not None

    # -- input -----------------------------------------------------------------------------
    def handle(self, msg: Any, link: str, peer: Hashable, wall_t: float) -> tuple[list[Reply], list[ProtocolEvent]]:
        name = msg.get_type()
        handler = getattr(self, f"_on_{name.lower()}", None)
        if handler is None:
            return [], []
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        return handler(msg, partner, link, peer, wall_t)

    def poll(self, wall_t: float) -> list[Reply]:
        """Wall-clock duties: re-request a stalled upload item, or give the upload up."""
        up = self._upload
        if up is None:
            return []
        if wall_t - up.last_progress_wall > self._timeout_s:
            self._upload = None
            self.counters["upload_timeout"] += 1
            return []
        if wall_t - up.last_request_wall >= self._retry_s:
            up.last_request_wall = wall_t
            self.counters["request_retry"] += 1
            return [self._request(up)]
        return []

    # -- helpers ---------------------------------------------------------------------------
    def _ack(self, partner: tuple[int, int], link: str, peer: Hashable, result: int, mission_type: int) -> Reply:
        if result != mavlink.MAV_MISSION_ACCEPTED:
            self.counters[f"ack_error_{result}"] += 1
        return Reply(self._mav.mission_ack_encode(partner[0], partner[1], result, mission_type), link, peer)

    def _request(self, up: _Upload) -> Reply:
        return Reply(self._mav.mission_request_int_encode(up.partner[0], up.partner[1], up.next_seq, up.mission_type),
                     up.link, up.peer)

    def _for_us(self, msg: Any) -> bool:
        ok = msg.target_system in (0, self._sysid) and msg.target_component in (0, self._compid)
        if not ok:
            self.counters["wrong_target"] += 1
        return ok

    def _upload_live(self, wall_t: float) -> _Upload | None:
        up = self._upload
        if up is not None and wall_t - up.last_progress_wall > self._timeout_s:
            self._upload = None
            self.counters["upload_timeout"] += 1
            return None
        return up

    # -- upload ----------------------------------------------------------------------------
    def _on_mission_count(self, msg, partner, link, peer, wall_t):
        if not self._for_us(msg):
            return [], []
        mtype = int(getattr(msg, "mission_type", MISSION))
        if mtype not in self._plans:
            return [self._ack(partner, link, peer, mavlink.MAV_MISSION_UNSUPPORTED, mtype)], []
        up = self._upload_live(wall_t)
        if up is not None and up.partner != partner:
            return [self._ack(partner, link, peer, mavlink.MAV_MISSION_DENIED, mtype)], []
        self._upload = None  # a new COUNT from the same partner restarts its upload
        if msg.count > MAX_ITEMS[mtype]:
            return [self._ack(partner, link, peer, mavlink.MAV_MISSION_NO_SPACE, mtype)], []
        if msg.count == 0:
            self._plans[mtype] = ()
            if mtype == MISSION:
                self.current_seq = 0
            return ([self._ack(partner, link, peer, mavlink.MAV_MISSION_ACCEPTED, mtype)],
                    [ProtocolEvent("cleared", mtype)])
        self._upload = _Upload(mtype, int(msg.count), partner, link, peer, [], wall_t, wall_t, wall_t)
        self._last_done = None
        return [self._request(self._upload)], []

    def _on_mission_item_int(self, msg, partner, link, peer, wall_t):
        if not self._for_us(msg):
            return [], []
        item = MissionItem(int(msg.seq), int(msg.frame), int(msg.command), int(msg.current),
                           int(msg.autocontinue), float(msg.param1), float(msg.param2), float(msg.param3),
                           float(msg.param4), int(msg.x), int(msg.y), float(msg.z),
                           int(getattr(msg, "mission_type", MISSION)))
        return self._on_item(item, partner, link, peer, wall_t)

    def _on_mission_item(self, msg, partner, link, peer, wall_t):
        """Legacy float items (MAVProxy, old GCS): degrees become degE7 as PX4 does."""
        if not self._for_us(msg):
            return [], []
        scale = 1e7 if int(msg.frame) in GLOBAL_FRAMES else 1.0
        x, y = float(msg.x), float(msg.y)
        if not (math.isfinite(x) and math.isfinite(y)) or abs(x * scale) > 2**31 - 1 or abs(y * scale) > 2**31 - 1:
            mtype = int(getattr(msg, "mission_type", MISSION))
            return [self._ack(partner, link, peer, mavlink.MAV_MISSION_INVALID_PARAM5_X, mtype)], []
        item = MissionItem(int(msg.seq), int(msg.frame), int(msg.command), int(msg.current),
                           int(msg.autocontinue), float(msg.param1), float(msg.param2), float(msg.param3),
                           float(msg.param4), int(round(x * scale)), int(round(y * scale)), float(msg.z),
                           int(getattr(msg, "mission_type", MISSION)))
        return self._on_item(item, partner, link, peer, wall_t)

    def _on_item(self, item: MissionItem, partner, link, peer, wall_t):
        up = self._upload_live(wall_t)
        if up is None:
            done = self._last_done
            if done is not None and done[0] == partner and done[1] == item.mission_type and item.seq == done[2] - 1:
                # Our final ACK was lost and the partner resent the last item: ACK again.
                return [self._ack(partner, link, peer, mavlink.MAV_MISSION_ACCEPTED, item.mission_type)], []
            self.counters["item_without_upload"] += 1
            return [], []
        if partner != up.partner:
            self.counters["item_from_other_partner"] += 1
            return [], []
        if item.mission_type != up.mission_type:
            self._upload = None
            return [self._ack(partner, link, peer, mavlink.MAV_MISSION_ERROR, up.mission_type)], []
        if item.seq < up.next_seq:  # a duplicate: ask again for the one we need
            self.counters["duplicate_item"] += 1
            up.last_request_wall = wall_t
            return [self._request(up)], []
        if item.seq > up.next_seq:
            self._upload = None
            return [self._ack(partner, link, peer, mavlink.MAV_MISSION_INVALID_SEQUENCE, up.mission_type)], []
        result = validate_item(item)
        if result != mavlink.MAV_MISSION_ACCEPTED:
            self._upload = None
            return [self._ack(partner, link, peer, result, up.mission_type)], []
        up.items.append(item)
        up.last_progress_wall = up.last_request_wall = wall_t
        if up.next_seq < up.count:
            return [self._request(up)], []
        self._plans[up.mission_type] = tuple(up.items)
        if up.mission_type == MISSION:
            self.current_seq = 0
        self._upload = None
        self._last_done = (partner, up.mission_type, up.count)
        return ([self._ack(partner, link, peer, mavlink.MAV_MISSION_ACCEPTED, up.mission_type)],
                [ProtocolEvent("replaced", up.mission_type)])

    def _on_mission_ack(self, msg, partner, link, peer, wall_t):
        """The partner ends an upload (cancel) or confirms a download (nothing to do)."""
        if not self._for_us(msg):
            return [], []
        up = self._upload
        if up is not None and up.partner == partner:
            self._upload = None
            self.counters["upload_cancelled"] += 1
        return [], []

    # -- download --------------------------------------------------------------------------
    def _on_mission_request_list(self, msg, partner, link, peer, wall_t):
        if not self._for_us(msg):
            return [], []
        mtype = int(getattr(msg, "mission_type", MISSION))
        if mtype not in self._plans:
            return [self._ack(partner, link, peer, mavlink.MAV_MISSION_UNSUPPORTED, mtype)], []
        count = len(self._plans[mtype])
        return [Reply(self._mav.mission_count_encode(partner[0], partner[1], count, mtype), link, peer)], []

    def _item_for(self, msg, partner, link, peer) -> tuple[MissionItem | None, list[Reply]]:
        mtype = int(getattr(msg, "mission_type", MISSION))
        if mtype not in self._plans:
            return None, [self._ack(partner, link, peer, mavlink.MAV_MISSION_UNSUPPORTED, mtype)]
        plan = self._plans[mtype]
        if not 0 <= msg.seq < len(plan):
            return None, [self._ack(partner, link, peer, mavlink.MAV_MISSION_INVALID_SEQUENCE, mtype)]
        item = plan[msg.seq]
        if mtype == MISSION:
            item = replace(item, current=1 if item.seq == self.current_seq else 0)
        return item, []

    def _on_mission_request_int(self, msg, partner, link, peer, wall_t):
        if not self._for_us(msg):
            return [], []
        item, err = self._item_for(msg, partner, link, peer)
        if item is None:
            return err, []
        out = self._mav.mission_item_int_encode(
            partner[0], partner[1], item.seq, item.frame, item.command, item.current, item.autocontinue,
            item.param1, item.param2, item.param3, item.param4, item.x, item.y, item.z, item.mission_type)
        return [Reply(out, link, peer)], []

    def _on_mission_request(self, msg, partner, link, peer, wall_t):
        """Legacy download request: answer with a float MISSION_ITEM."""
        if not self._for_us(msg):
            return [], []
        item, err = self._item_for(msg, partner, link, peer)
        if item is None:
            return err, []
        scale = 1e-7 if item.frame in GLOBAL_FRAMES else 1.0
        out = self._mav.mission_item_encode(
            partner[0], partner[1], item.seq, item.frame, item.command, item.current, item.autocontinue,
            item.param1, item.param2, item.param3, item.param4, item.x * scale, item.y * scale, item.z,
            item.mission_type)
        return [Reply(out, link, peer)], []

    # -- clear -----------------------------------------------------------------------------
    def _on_mission_clear_all(self, msg, partner, link, peer, wall_t):
        if not self._for_us(msg):
            return [], []
        mtype = int(getattr(msg, "mission_type", MISSION))
        if mtype == ALL_TYPES:
            types = list(self._plans)
        elif mtype in self._plans:
            types = [mtype]
        else:
            return [self._ack(partner, link, peer, mavlink.MAV_MISSION_UNSUPPORTED, mtype)], []
        if self._upload is not None and self._upload.mission_type in types:
            self._upload = None
        for t in types:
            self._plans[t] = ()
        if MISSION in types:
            self.current_seq = 0
        return ([self._ack(partner, link, peer, mavlink.MAV_MISSION_ACCEPTED, mtype)],
                [ProtocolEvent("cleared", t) for t in types])
