"""calibrate (node): the calibration engine on bags or the recorder's bag, and the skin frames on /tf_static.

``ros2 run nao_skin calibrate --ros-args -p inputs:=[bag, ...] -p calibrate_on_start:=true`` calibrates at
start; in a record session (``record.launch.py``) it waits for a request: the ``~/calibrate`` service (below) or
``nao_skin/calibrate`` (std_msgs/String: paths separated by spaces/newlines; empty = ``inputs``, else the
recorder's bag ``recording``). Results go to
``out_dir`` (calibration.yaml, taxel files, report) through
:func:`nao_skin.calibration.pipeline.calibrate_recordings`, exactly as ``nao-skin calibrate``.

Skin frames: this node is the ONE publisher of every skin frame (mount,
patches, triangles of every part, parents and poses as in
``SkinCalibration.to_dict``). At start it publishes the calibration it is
given (``calibration``, nominal by default); after each calibration it
publishes the complete new set, in one ``tf2_msgs/TFMessage`` on
``/tf_static`` (reliable, transient local, depth 1), so a subscriber
joining at any time gets exactly the latest calibration. robot_state_publisher
must get the URDF without skin frames (xacro arg ``skin_frames:=false``) so
that no frame has two publishers.

Status on ``/nao_skin/calibration/status`` (std_msgs/String, JSON, latched); when a live session ends, a final
update calibrates the touches since the last one, and the status says ``ended`` and where the calibration is.
With every calibration it publishes, the uncertainty map on ``/nao_skin/calibration/uncertainty``
(visualization_msgs/MarkerArray, latched): a disc over each triangle of the calibrated parts, in the triangle's
frame, coloured by its predicted error (:mod:`nao_skin.calibration.uncertainty_map`; namespace = part, id = triangle).

``~/calibrate`` (``std_srvs/srv/Trigger``, ``ros2 service call /calibrate/calibrate std_srvs/srv/Trigger``) is
an empty request answered with its result once the calibration has ended: ``success`` whether it succeeded,
``message`` where it was written or the one line saying why not (one is running, no inputs, the calibration
failed). The node's other callbacks go on meanwhile. The calibration at start (``calibrate_on_start``) that
fails ends the node, in its one line and exit code 2, except in a live record session. The live schedule
(``live_every_touches``, ``live_period``), the guidance and ``plots`` apply when set (``ros2 param set``); the
node's state is on ``/diagnostics``.
"""
from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.task import Future
from std_msgs.msg import ColorRGBA, String
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from nao_skin.calibration.uncertainty_map import colours, triangle_discs
from nao_skin.errors import DataError, NaoSkinError, one_line
from nao_skin.formats.outdir import output_stamp
from nao_skin.live.diagnostics import age_check, live_check
from nao_skin.live.updates import PartStates, UpdateSchedule
from nao_skin.model.skin import SkinCalibration, skin_frame_transforms
from nao_skin.nodes.diagnostics import publish_diagnostics
from nao_skin.nodes.runtime import declare, run_node
from nao_skin.nodes.static_tf import latched_tf_static_publisher, to_transform_stamped
from nao_skin.nodes.topics import (GUIDANCE_TOPIC, LATCHED, MAX_SKIPPED_SAID, PROGRESS_TOPIC, REQUEST_TOPIC,
                                   STATUS_TOPIC, UNCERTAINTY_TOPIC, frame_prefix)
from nao_skin.plain import jsonable
from nao_skin.session.live import LiveCalibration, request_out_dir, session_end_out_dir
from nao_skin.session.params import (CALIBRATE, changeable_params, guidance_pairs, options_from_params,
                                     skin_from_params)


# The session's end (Ctrl-C of nao-skin record) is bounded, also on a busy machine: the last accepted live
# calibration is written first; a live update still running is stopped at its next stage (the final update covers
# its touches); the final update has its own time, past which it is abandoned and what was written stays.
STOP_JOIN_S = 2.0       # at the session's end: how long a running live update or requested calibration may take to end
FINAL_WAIT_S = 2.0      # ... how long the final update waits for the recorder to close the bag (it does as it stops)
# ... how much computing the final update may take: CPU seconds of its thread, not wall time, so that what the
# session's end writes depends on the touches and never on how busy the machine is (tenths of a second for a
# warm update of a thousand touches; a refresh from scratch of thousands of touches may not fit)
FINAL_BUDGET_S = 2.0
FINAL_ACK_S = 1.0       # ... and how long the last status and frames may take to reach their subscribers


class CalibrateNode(Node):
    def __init__(self, **kwargs):
        super().__init__("calibrate", **kwargs)
        self.p = declare(self, CALIBRATE, changeable=lambda values: changeable_params("calibrate", values),
                         on_change=self._on_params)
        if self.p["out_dir"]:     # 'cal/' and './cal' are 'cal': its places beside are 'cal.new', never 'cal/.new'
            self.p["out_dir"] = os.path.normpath(self.p["out_dir"])
        self.options = options_from_params(self.p)      # a wrong value stops the node at start, in one line
        self.skin = skin_from_params(self.p)
        self.prior = (SkinCalibration.load(self.p["calibration"], self.skin) if self.p["calibration"]
                      else self.skin.zero_calibration())
        self.tf_pub = latched_tf_static_publisher(self)
        self.status_pub = self.create_publisher(String, STATUS_TOPIC, LATCHED)
        self.guidance_pub = self.create_publisher(String, GUIDANCE_TOPIC, LATCHED)
        self.uncertainty_pub = self.create_publisher(MarkerArray, UNCERTAINTY_TOPIC, LATCHED)
        self.generation = 0
        self._busy = threading.Lock()
        self._publishing = threading.Lock()   # a calibration's end is said before the next one's start
        self._worker = None
        self._requested_out = None        # (path, output_stamp) of the last requested calibration's output
        self._out_dir_at_start = output_stamp(self.p["out_dir"])
        self._latched: dict = {}          # the status last published (latched)
        self._ignored = 0                 # requests refused while one calibration or update was running
        self._ended = False               # the session's end is published: nothing is published after it
        self._written_stamp = None        # output_stamp of what the session's end wrote first, to replace
        self._guidance_sequence = 0       # guidance messages published
        self._on_tf = None                # what the frames on /tf_static are (a result, or a calibration): the
        #                                   guidance is computed under it
        self._touches = None              # the session's touches the last live update read (the guidance's)
        self._stopping = threading.Event()    # the session ends: a live update running stops at its next stage
        self.publish_calibration(self.prior, "initial" if self.p["calibration"] else "nominal")
        self.create_subscription(String, REQUEST_TOPIC, self._on_request, 10)
        # its callback awaits the calibration's end: in a group of its own, reentrant, else the pending callback
        # would hold back every other callback of the node's (mutually exclusive) default group, a second call
        # too, until then (one executor thread: the callbacks still run one at a time)
        self.create_service(Trigger, "~/calibrate", self._on_trigger, callback_group=ReentrantCallbackGroup())
        self._progress_at = None          # monotonic time of the last progress message (live)
        self._touch_at = None             # ... and of the last one that counted a new touch
        self._update_at = None            # ... and when the last live update started
        self.guidance_pairs = guidance_pairs(self.p, self.skin)
        if self.p["live"]:
            self._check_live_out_dir()    # refused now, not after an hour at the robot
            self.schedule = UpdateSchedule(int(self.p["live_every_touches"]), float(self.p["live_period"]))
            self.live = LiveCalibration(self.skin, self.options, self.p["recording"], self.prior,
                                        float(self.p["live_refresh"]),
                                        PartStates(float(self.p["live_done_median_mm"]),
                                                   float(self.p["live_done_p95_mm"]), float(self.p["live_done_margin"])),
                                        float(self.p["live_max_move_mm"]), earlier=self._earlier(),
                                        scratch_below=int(self.p["live_scratch_below"]))
            # a bad bag: one line and exit 2, now; what is worth a look (skips, a sitting they continue left out)
            # as warnings
            if self.live.read_earlier(log=self.get_logger().info, summary=self.get_logger().warning):
                self.schedule.again()     # their calibration on /tf_static at once, before the first new touch
            self._recorded = 0            # touches the recorder reported so far
            self._repeats_said = False    # the recording repeats the earlier sittings' touches: said once
            self._retried = False         # an update found no new touch in the bag and tries once more
            self._malformed = 0           # progress messages skipped
            self.create_subscription(String, PROGRESS_TOPIC, self._on_progress, 10)
            self.create_timer(0.5, self._maybe_update)
        publish_diagnostics(self, self._diagnostics)
        inputs = [i for i in self.p["inputs"] if i]
        # the calibration at start is the node's job (calibrate.launch.py, ros2 run ... calibrate_on_start:=true):
        # when it fails the node ends, in its one line and exit 2, rather than publish nominal frames on as if it
        # had worked; in a live record session the session goes on (the recording matters more)
        self._failed = None               # the failure the node ends with (set by the worker thread)
        self._end = self.create_guard_condition(self._end_failed)
        if self.p["calibrate_on_start"]:
            self._check_start(inputs)     # refused now, in one line and exit 2, not logged by a node that runs on
            self._start(inputs, ends_on_failure=not self._is_session())

    def publish_calibration(self, calib: SkinCalibration, source: str, quiet: bool = False, result=None) -> None:
        """All skin frames in ONE latched TFMessage: late joiners get exactly this set (in a namespace, the
        frames carry it as a prefix, as robot_state_publisher's frame_prefix makes the body's). ``result``: the
        calibration's result (its held frames and parts), for the guidance that follows."""
        stamp = self.get_clock().now().to_msg()
        ns = frame_prefix(self)
        self.tf_pub.publish(TFMessage(transforms=[to_transform_stamped(ns + parent, ns + child, t, stamp)
                                                  for parent, child, t in skin_frame_transforms(self.skin, calib)]))
        self.generation += 1
        self._on_tf = result if result is not None else calib
        if result is not None:
            self._publish_uncertainty(result.report.final.get("predicted_triangle_error_mm") or {}, stamp, ns)
        if not quiet:                     # a live update says more in its own status
            self._status({"state": "published", "source": source, "generation": self.generation})

    # ------------------------------------------------------------------ live updates
    def _publish_uncertainty(self, triangles: dict, stamp, ns: str) -> None:
        """The uncertainty map of the calibration just published (every marker of the last one replaced)."""
        markers = [Marker(action=Marker.DELETEALL)]
        for name, values in triangles.items():
            part = self.skin.parts[name]
            discs = triangle_discs(part, values)
            for (tid, centre, diameter, _), rgba in zip(discs, colours([d[3] for d in discs])):
                m = Marker(type=Marker.CYLINDER, action=Marker.ADD, ns=name, id=tid, frame_locked=True)
                m.header.frame_id, m.header.stamp = ns + part.triangle_frame(tid), stamp
                m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(v) for v in centre)
                m.pose.orientation.w = 1.0
                m.scale.x = m.scale.y = float(diameter)
                m.scale.z = 0.0005
                m.color = ColorRGBA(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))
                markers.append(m)
        self.uncertainty_pub.publish(MarkerArray(markers=markers))

    def _on_progress(self, msg: String) -> None:
        try:
            touches = json.loads(msg.data).get("touches", 0)
        except (ValueError, AttributeError, RecursionError):
            touches = None
        if isinstance(touches, int) and not isinstance(touches, bool) and touches >= 0:
            now = time.monotonic()
            self._progress_at = now
            if touches > self._recorded:
                self._touch_at = now
            self._recorded = touches
            return
        self._malformed += 1              # the next one will do; said, as any message skipped is
        if self._malformed <= MAX_SKIPPED_SAID:
            self.get_logger().warning(f"skipped a malformed {PROGRESS_TOPIC} message ({msg.data[:80]!r}: expected"
                                      f" JSON with a 'touches' count)")

    def _check_live_out_dir(self, out_dir: str | None = None) -> None:
        """Where the session's last live calibration goes: replaced when the session ends (force), never when
        it holds what the node reads (the recording, the calibration it started from, the skin's files)."""
        from nao_skin.calibration.pipeline import check_output

        check_output(out_dir or self.p["out_dir"], [self.p["recording"], *self._earlier(), self.p["calibration"],
                                                    self.p["skin_config"], *self.skin.source_files()],
                     force=True, label="out_dir")

    def _earlier(self) -> list:
        """The bags of earlier sittings this session continues (``earlier_recordings``)."""
        return [path for path in self.p["earlier_recordings"] if path]

    def _check_start(self, inputs: list) -> None:
        """What the calibration at start reads and where it writes, as a request checks them: an input that is
        not there, an out_dir that holds an input or what nao-skin did not write, one that cannot be written."""
        from nao_skin.calibration.pipeline import check_output
        from nao_skin.errors import DataError

        if not inputs:
            raise DataError("parameter inputs: empty; calibrate_on_start needs the bags (or .txt files) to calibrate")
        for path in inputs:
            if not os.path.exists(path):
                what = "a link to nothing" if os.path.lexists(path) else "no such file or directory"
                raise DataError(f"parameter inputs: {path}: {what}")
        self._inputs(inputs)
        check_output(self.p["out_dir"], [*inputs, self.p["skin_config"], self.p["calibration"],
                                         *self.skin.source_files()], force=True, label="out_dir")

    def _inputs(self, paths: list):
        """``paths`` with the fingertips that pressed their text inputs' touches (parameter ``fingertips``)."""
        from nao_skin.formats.inputs import Inputs, parse_fingertips

        named = [f for f in self.p["fingertips"] if f]
        return Inputs(tuple(paths), parse_fingertips(named, paths, said=lambda item: f"parameter fingertips: {item!r}") if named else {})

    def _maybe_update(self) -> None:
        now = time.monotonic()
        if not self.p["recording"] or not self.schedule.due(self._recorded, now) \
                or not self._busy.acquire(blocking=False):     # a calibration is running: the next tick
            return
        self.schedule.started(self._recorded, now)
        self._update_at = now
        self._ignored = 0                 # counted per calibration or update
        self._worker = threading.Thread(target=self._live_update, daemon=True, name="live calibration")
        self._worker.start()

    def _live_update(self) -> None:
        """One live update (:class:`~nao_skin.session.live.LiveCalibration`): published only when it succeeds,
        a failed one leaves the last good frames on /tf_static. Then the guidance: where touches would help
        most now (also while waiting for a first calibration)."""
        log = self.get_logger()
        try:
            out = self.live.update(log=log.debug, stop=self._stopping.is_set)
            if out.status.get("state") == "stopped":     # the session ends: the final update covers its touches
                return
            # (also when they add nothing to calibrate: all of them repeats, the update is skipped)
            if self.live.repeated and not self._repeats_said:      # said while the operator can still act
                self._repeats_said = True
                log.warning(f"{self.live.repeated} of the {self.live.recorded} touches recorded so far repeat touches"
                            f" of the earlier sittings' bags exactly and are left out: a simulated robot playing an"
                            f" earlier sitting's seed again? (record.launch.py seed:=N, nao-skin record --seed N:"
                            f" one no sitting played)")
            if not out.status:      # the bag has no touch since the last update yet (not flushed)
                if not self._retried:       # once at the next tick; then the schedule as usual (a touch the
                    self._retried = True    # reading drops as a duplicate would keep the recorder's count ahead)
                    self.schedule.again()
                return
            self._retried = False
            if self._ended:           # a live update that outlived close()'s wait: the session is over
                return
            try:
                if out.accepted is not None:
                    self.publish_calibration(out.accepted.calibration, "live update", quiet=True, result=out.accepted)
                    for line in out.accepted.report.warnings:
                        log.warning(f"live update {self.generation}: {line}")
                    log.info(f"live update {self.generation}: {out.status['touches']} touches, taxels moved up to"
                             f" {max(out.status['displacement_mm'].values(), default=0.0):.2f} mm")
                elif out.status["state"] == "failed":
                    log.error(f"live update failed: {out.status['error']}")
                self._status({**out.status, "live": True, "generation": self.generation})
            except Exception as exc:  # noqa: BLE001 - the status must not stay at the last update's
                log.error(f"live update not published: {one_line(exc)}")
                self._status({"state": "failed", "live": True, "error": one_line(exc), "generation": self.generation,
                              "parts": self.live.parts_state()})
            if out.touches is not None:
                self._touches = out.touches
                if not self._stopping.is_set():     # the session ends: the final update's guidance follows
                    self._try_guidance(out.status)
        finally:
            self._busy.release()

    def _try_guidance(self, status: dict) -> None:
        """The guidance, after each live update and each publication of frames in a live session (the final
        update's, a requested calibration's): its generation follows /tf_static's. Advice: its failure is a
        warning, never the session's end."""
        if not (self.p["live"] and self.p["guidance"]) or self._touches is None:
            return
        try:
            self._publish_guidance(self._touches, status)
        except Exception as exc:  # noqa: BLE001 - guidance is advice: its failure never stops the session
            self.get_logger().warning(f"guidance not updated: {one_line(exc)}")

    def _publish_guidance(self, touches, status: dict) -> None:
        """Where to touch next under the calibration on /tf_static (the last accepted live update's, the one the
        node started from before the first, or a requested calibration's published since), latched JSON;
        ``generation``: that calibration's on /tf_static, ``sequence``: this guidance's own count."""
        from nao_skin.guidance.capture import guidance

        live = self._on_tf is self.live.last or isinstance(self._on_tf, SkinCalibration)
        advice = guidance(touches, self.skin, self._on_tf, self.options, pairs=self.guidance_pairs,
                          max_targets=int(self.p["guidance_targets"]), seed=self.generation,
                          # a requested calibration's parts are its report's; else the live updates'
                          calibrated_parts=self.live.updates.calibrated_parts if live else None)
        if status.get("state") == "failed":     # said: the targets come from an older calibration than the touches
            what = ("the last accepted calibration" if self._on_tf is self.live.last
                    else "the calibration published last")
            advice.notes.append(f"the last live update failed ({status.get('error')}); these targets are under"
                                f" {what} (generation {self.generation})")
        self._guidance_sequence += 1
        self.guidance_pub.publish(String(data=json.dumps({"generation": self.generation,
                                                          "sequence": self._guidance_sequence, **advice.to_dict()},
                                                         sort_keys=True)))

    def _status(self, info: dict) -> None:
        self._latched = info
        # plain JSON (NaN as null, numpy as Python); anything else, e.g. a path, as its text
        self.status_pub.publish(String(data=json.dumps(jsonable(info), sort_keys=True, default=str)))

    def _on_request(self, msg: String) -> None:
        paths = request_paths(msg.data)
        if not paths:
            paths = [i for i in self.p["inputs"] if i] or self._session_inputs()
        self._start(paths)

    async def _on_trigger(self, request, response):
        """``~/calibrate``: an empty request (the node's inputs, else the session's bags), answered with the
        calibration's result once it has ended: success, and where it was written or the one line saying why
        not. Awaited, not waited for: the executor goes on with the node's other callbacks meanwhile (rclpy
        resumes the callback at its next turn once the worker has set the future)."""
        answer = Future()
        started, message = self._start([i for i in self.p["inputs"] if i] or self._session_inputs(), answer=answer)
        response.success, response.message = (await answer) if started else (False, message)
        return response

    def _on_params(self, changed: dict) -> None:
        """A changeable parameter set (``ros2 param set``): the live schedule takes it at its next check, the
        guidance and plots at their next use."""
        self.p.update(changed)
        if "live_every_touches" in changed:
            self.schedule.every_touches = int(changed["live_every_touches"])
        if "live_period" in changed:
            self.schedule.period = float(changed["live_period"])
        self.get_logger().info("applied " + ", ".join(f"{k}:={v!r}" for k, v in sorted(changed.items())))

    def _diagnostics(self, now: float) -> list:
        """The node's state, and in a live session how long ago the recorder last reported and counted a touch
        and the last update ran."""
        checks = [live_check(self._latched, bool(self.p["live"]), self._busy.locked())]
        if self.p["live"]:
            def age(at):
                return None if at is None else now - at

            checks += [age_check("recorder progress", age(self._progress_at)), age_check("touch", age(self._touch_at)),
                       age_check("live update", age(self._update_at))]
        return checks

    def _session_inputs(self) -> list:
        """What an empty request calibrates in a record session: the recording, after the earlier sittings' bags
        it continues (before its first touch, those alone)."""
        recording = self.p["recording"]
        if not recording:
            return []
        earlier = self._earlier()
        return [*earlier, recording] if not earlier or os.path.lexists(recording) else earlier

    def _is_session(self) -> bool:
        """A live record session's node (not calibrate.launch.py's, nor one started alone on its inputs)."""
        return bool(self.p["live"] and self.p["recording"])

    def _end_failed(self) -> None:
        """The calibration at start failed: the node ends, its line said by run_node (exit 2)."""
        if self._failed is not None:
            raise self._failed

    def _start(self, paths: list, ends_on_failure: bool = False, answer: Future | None = None) -> tuple:
        """A calibration of ``paths`` started in the background: ``(True, what)``, or ``(False, why not)``.
        ``ends_on_failure``: the node ends when it fails (the calibration at start); ``answer``: a future given
        ``(succeeded, where it was written or why not)`` when it has ended."""
        if not paths:
            error = "no input: set 'inputs' or 'recording', or name bags"
            self.get_logger().error(f"calibration request refused: {error}")
            self._status({"state": "failed", "error": error})
            return False, error
        if not self._busy.acquire(blocking=False):
            # the latched state stays the one of what is running (a calibration, a live update); the refusal
            # is counted in it and logged
            self._ignored += 1
            self._status({**self._latched, "ignored_requests": self._ignored})
            refused = f"a calibration or live update is running; request for {' '.join(paths)} ignored"
            self.get_logger().warning(refused)
            return False, f"{refused} (its result comes on {self.status_pub.topic_name})"
        self._ignored = 0
        with self._publishing:
            self._status({"state": "running", "inputs": paths})
        self._worker = threading.Thread(target=self._run, args=(paths, ends_on_failure, answer), daemon=True,
                                        name=f"calibration of {' '.join(paths)}")
        self._worker.start()
        return True, f"calibrating {' '.join(paths)} -> {self.p['out_dir']} (status on {self.status_pub.topic_name})"

    def _run(self, paths: list, ends_on_failure: bool = False, answer: Future | None = None) -> None:
        from nao_skin.calibration.pipeline import calibrate_recordings, check_output

        p = self.p
        log = self.get_logger()
        ended = None          # the status saying how it ended: published once the next request may start
        result = None         # the answer: (succeeded, where it was written or why not)
        try:
            # the node replaces its own last output on every success (force), never a calibration it did not
            # write, one that holds an input or files nao-skin did not write; checked per request, before loading
            protected = [p["skin_config"], p["calibration"]]
            out_dir, replacing, beside = request_out_dir(p["out_dir"], self._requested_out)
            if beside:      # out_dir holds something: refused as ever when it is an input or not nao-skin's
                check_output(p["out_dir"], [*paths, *protected, *self.skin.source_files()], force=True,
                             label="out_dir")
                log.warning(beside)
            # every request starts where the node did (``calibration``, or nominal), as nao-skin calibrate does:
            # the same request gives the same calibration; only the place written may be the node's last output
            run = calibrate_recordings(self._inputs(paths), self.skin, self.options, out_dir, prior=self.prior,
                                       force=True, plots=bool(p["plots"]), label="out_dir", protected=protected,
                                       command="calibrate (node)", log=log.info, summary=log.warning,
                                       replacing=replacing, beside=".new")
            self._requested_out = (str(run.out_dir), output_stamp(run.out_dir))    # the node's own, to replace
            calibration = str(run.out_dir / "calibration.yaml")
            self.publish_calibration(run.result.calibration, calibration, result=run.result)
            final = run.result.report.final
            ended = {"state": "done", "generation": self.generation, "out_dir": str(run.out_dir),
                     "calibration": calibration, "touches": run.n_touches,
                     "final": {k: final.get(k) for k in ("train", "test") if k in final},
                     "warnings": run.result.report.warnings}
            self._try_guidance(ended)      # in a live session: under these frames
            said = f"calibrated from {len(paths)} input(s): {run.n_touches} touches -> {run.out_dir}"
            log.info(said)
            for line in run.result.report.warnings:
                log.warning(line)
            result = (True, said + (f" ({len(run.result.report.warnings)} warnings: {self.status_pub.topic_name})"
                                    if run.result.report.warnings else ""))
        except NaoSkinError as exc:
            ended, result = self._failed_with(exc, str(exc), ends_on_failure)
        except Exception as exc:  # noqa: BLE001 - whatever breaks, the latched status must not stay "running"
            ended, result = self._failed_with(exc, f"calibration failed: internal error: {one_line(exc)}",
                                              ends_on_failure)
        finally:
            # its end is said before the next request's "running", and only once that request may start
            with self._publishing:
                self._busy.release()
                if ended is not None:
                    self._status(ended)
            if self._failed is not None:
                self._end.trigger()
            if answer is not None:
                answer.set_result(result or (False, "stopped"))

    def _failed_with(self, exc: Exception, line: str, ends: bool) -> tuple:
        """A calibration failed: ``(the status saying so, the answer)``; the node logs the line and goes on, or
        (``ends``) ends with it as its one line."""
        if ends:
            self._failed = exc if isinstance(exc, NaoSkinError) else DataError(line)
        else:
            self.get_logger().error(line)
        error = line if isinstance(exc, NaoSkinError) else f"internal error: {one_line(exc)}"
        return {"state": "failed", "error": error}, (False, line)

    def close(self) -> None:
        """End of the session: the last accepted live calibration is written where users apply it, at once
        (whatever comes next: an update that takes long, ros2 launch's SIGKILL about 10 s after Ctrl-C); then the
        touches recorded since it are calibrated too (a final update) and written over it. Each step is bounded
        (STOP_JOIN_S, FINAL_WAIT_S, FINAL_BUDGET_S): a live update still running is stopped, not waited for."""
        self._stopping.set()
        session = self.p["live"] and self.p["recording"]     # a live record session (not calibrate.launch.py)
        written = self.live.last if session else None
        out = self._write_live(written) if written is not None else None
        if self._worker is not None:
            self._worker.join(timeout=STOP_JOIN_S)
            if self._worker.is_alive():   # a daemon thread: it ends with the process, its output unwritten
                self.get_logger().warning(f"stopped during the {self._worker.name}: it is written only if it had"
                                          f" got to its output (a staging directory it left beside out_dir is"
                                          f" removed, an earlier output it had moved aside put back, by the next"
                                          f" calibration written there)")
        if not session:
            if self._failed is not None:      # the failed status reaches its subscribers before the node goes
                self.status_pub.wait_for_all_acked(Duration(seconds=FINAL_ACK_S))
            return
        complete = False                  # what is written covers every touch of the closed recording
        if not (self._worker is not None and self._worker.is_alive()):
            complete = self._final_update()
        if self.live.last is not None and self.live.last is not written:      # an update accepted since
            out = self._write_live(self.live.last, out)
        self._ended = True
        if out is None:                   # a short session, or one whose touches never sufficed: say so
            latched = self._latched
            why = {"waiting": latched.get("reason"), "failed": latched.get("error")}.get(latched.get("state"),
                                                                                      "no live update ran")
            self.get_logger().warning(f"the session ends without a live calibration ({why}): none is written to"
                                      f" {self.p['out_dir']}")
            self._final_status({"state": "ended", "generation": self.generation, "calibration": None, "reason": why,
                                "recorded": self.live.read_count, "duplicates": self.live.duplicates,
                                **({"earlier": self.live.earlier_count} if self.live.earlier else {})})
            return
        n, read = self.live.last_count, self.live.read_count
        covered = (f"all {n} touches" if complete and n >= read else f"{n} of {read} touches" if n < read
                   else f"{n} touches")
        if self.live.earlier_count:
            covered += f", {self.live.earlier_count} of them from the earlier sittings' bags"
        if self.live.duplicates:           # the recorder's count includes them
            covered += (f"; {self.live.duplicates} exact duplicates in the {'bags' if self.live.earlier else 'bag'}"
                        f" left out")
        self.get_logger().info(f"the last live calibration ({covered}) -> {out}")
        self._final_status({"state": "ended", "generation": self.generation, "out_dir": str(out),
                            "calibration": str(out / "calibration.yaml"), "touches": n, "recorded": read,
                            # the bag's exact duplicates, left out of 'recorded' (the recorder counted them)
                            "duplicates": self.live.duplicates, "complete": complete,
                            **({"earlier": self.live.earlier_count} if self.live.earlier else {}),
                            "parts": self.live.parts_state()})

    def _final_status(self, info: dict) -> None:
        """The session's last status, delivered before the node goes (the process ends right after: a
        subscriber missed it now and then)."""
        self._status(info)
        # one deadline for all three: a subscriber that is going too (the session's other nodes, when the
        # session's process died) acknowledges nothing, and a wait per publisher kept a node 3 s after
        # nao-skin record was killed (the bound is 2 s)
        deadline = time.monotonic() + FINAL_ACK_S
        for publisher in (self.status_pub, self.tf_pub, self.guidance_pub):
            publisher.wait_for_all_acked(Duration(seconds=max(0.0, deadline - time.monotonic())))

    def _write_live(self, result, written: Path | None = None) -> Path:
        """A live calibration ``result``, written to out_dir (or beside it: :func:`session_end_out_dir`);
        ``written``: where this session's end wrote one already, replaced."""
        from nao_skin.calibration.report import write_outputs

        out_dir, replacing = written, (self._written_stamp or ())
        if out_dir is None:
            requested = self._requested_out[1] if self._requested_out else None
            out_dir, replacing, moved = session_end_out_dir(self.p["out_dir"], self._out_dir_at_start, requested)
            if moved:
                self.get_logger().warning(moved)
        try:
            self._check_live_out_dir(out_dir)
            # a new place must still be free, the node's own requested calibration or the end's first write is the
            # one to replace: another process's output written there meanwhile stays, this one goes beside it
            wrote = write_outputs(result, self.skin, out_dir, plots=False, command="calibrate (node, live)",
                                  replacing=replacing, beside=".live")
            if Path(wrote) != Path(out_dir):
                self.get_logger().warning(f"{out_dir}: another output was written there during the session's end"
                                          f" and is left as it is; the session's live calibration goes to {wrote}")
            self._written_stamp = output_stamp(wrote)
            return wrote
        except NaoSkinError as exc:
            if written is not None:       # the later one is not written: the one written before stays
                self.get_logger().error(f"the final live calibration is not written ({exc}); {written} keeps the"
                                        f" one before")
                return written
            # the node's one line and exit 2; the touches are in the recording
            recording = self.p["recording"]
            error = (f"{exc}; the session's live calibration is not written: the session's touches are in the"
                     f" recording {recording} (the recorder's last line says how many), and"
                     f" {calibrate_again([*self._earlier(), recording])} calibrates them again")
            self._ended = True
            self._final_status({"state": "ended", "generation": self.generation, "calibration": None,
                                "error": error})
            raise type(exc)(error) from None

    def _final_update(self) -> bool:
        """The touches recorded since the last update calibrated too, once the recorder has closed the bag (it
        writes what it still holds as it stops); True when the last accepted calibration now covers every touch
        of the closed recording."""
        log = self.get_logger()
        if not self.live.recording_exists():     # no touch recorded: complete if the earlier sittings' all are
            return self.live.last is not None and self.live.last_count >= self.live.read_count
        if self.live.last is None and not self._recorded:
            return False             # no touch recorded (a first calibration needs 10 or more anyway)
        closed = self.live.wait_until_closed(FINAL_WAIT_S)
        if not closed:
            log.warning(f"the recorder has not closed {self.p['recording']} after {FINAL_WAIT_S:g} s; the final"
                        f" update calibrates the touches it has written")
        started = time.thread_time()
        out = self.live.update(log=log.debug, final=True,
                               stop=lambda: time.thread_time() - started > FINAL_BUDGET_S)
        if not out.status:          # no touch since the last accepted update
            return closed
        if out.status["state"] == "stopped":
            recording = [*self._earlier(), self.p["recording"]]
            had = (f"the last accepted update's, over {self.live.last_count} touches, is written" if self.live.last
                   is not None else "none is written")
            log.warning(f"the final live update over {out.status['touches']} touches was stopped after"
                        f" {out.status['seconds']:.1f} s ({FINAL_BUDGET_S:g} s of computing: the session's end waits"
                        f" no longer); {had}; {calibrate_again(recording)} calibrates every touch")
            self._status({**out.status, "live": True, "generation": self.generation})
            return False
        if out.accepted is not None:
            self.publish_calibration(out.accepted.calibration, "final live update", quiet=True, result=out.accepted)
            self._touches = out.touches
            log.info(f"final live update {self.generation}: {out.status['touches']} touches")
        elif self.live.last is not None:
            why = out.status.get("error") or out.status.get("reason")
            log.warning(f"the final live update over {self.live.read_count} touches was not accepted ({why});"
                        f" the last accepted update's is written")
        self._status({**out.status, "live": True, "generation": self.generation})
        if out.accepted is not None:      # the guidance under the frames published last, as after every update
            self._try_guidance(out.status)
        return closed and out.accepted is not None


def calibrate_again(paths: list) -> str:
    """How a user calibrates ``paths`` again, whichever way they work (a node cannot know)."""
    import shlex

    words = shlex.join(str(p) for p in paths)
    return (f"nao-skin calibrate {words} --out DIR (or ros2 launch nao_skin calibrate.launch.py"
            f" inputs:={shlex.quote(words)} out_dir:=DIR)")


def request_paths(text: str) -> list:
    """The inputs a request on /nao_skin/calibrate names: a JSON list of paths (one may hold a space), else the
    words of the text; none: the node's own."""
    if text.lstrip().startswith("["):
        try:
            paths = json.loads(text)
        except (ValueError, RecursionError):
            paths = None
        if isinstance(paths, list) and all(isinstance(p, str) for p in paths):
            return [p for p in paths if p]
    return text.split()


def main(args=None) -> int:
    return run_node(CalibrateNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
