#!/usr/bin/python3
"""Example: run an APC task on the cell from Python, through the orchestrator.

Starts the task of an APC 2016 task file (picking.orchestrator.v1.OrchestratorService/
StartTask with the file's JSON text), streams its events (WatchTask) until the task ends,
printing one line per event, then asks for the result (GetTask) and prints the score.

    /usr/bin/python3 clients/python/task_client.py --address 127.0.0.1:50050 \\
        --task data/apc2016/tasks/pick_layout_1.json

--result FILE also writes what happened as JSON (task id, final state, score, items moved,
the APC output file's contents and every event), for scripts and tests.

Exit status: 0 when the task finished (TASK_STATE_SUCCEEDED), 1 when it failed, was
cancelled or a call failed, 2 on bad usage.
"""

import argparse
import json
import pathlib
import sys

import grpc

import picking_stubs


def load_contract():
    """The orchestrator's generated messages and stub."""
    return (picking_stubs.load("picking.orchestrator.v1.orchestrator_pb2"),
            picking_stubs.load("picking.orchestrator.v1.orchestrator_pb2_grpc"))


def event_line(pb, event):
    """One event as one line: time, progress, item, step, outcome, state and message."""
    step = pb.Step.Name(event.step).removeprefix("STEP_") if event.step else "-"
    state = pb.TaskState.Name(event.state).removeprefix("TASK_STATE_")
    return (f"[{event.time_s:7.1f} s] #{event.sequence} {event.items_done}/{event.items_total} "
            f"{event.item or '-'} {step} {'ok' if event.step_ok else 'FAIL'} {state} "
            f"{event.message}")


def event_record(pb, event):
    """One event as a JSON-ready dict (enums by name)."""
    return {"sequence": event.sequence, "time_s": event.time_s, "item": event.item,
            "step": pb.Step.Name(event.step), "ok": event.step_ok,
            "message": event.message, "items_done": event.items_done,
            "items_total": event.items_total, "state": pb.TaskState.Name(event.state)}


def watch(pb, stub, task_id, timeout_s):
    """Streams the task's events until it ends; returns them as records."""
    events = []
    for response in stub.WatchTask(pb.WatchTaskRequest(task_id=task_id), timeout=timeout_s):
        event = response.event
        print(event_line(pb, event), flush=True)
        events.append(event_record(pb, event))
    return events


def summary(pb, task, events):
    """The task's end as a JSON-ready dict."""
    result = task.result
    return {"task_id": task.task_id, "state": pb.TaskState.Name(task.state),
            "error": task.error, "score": result.score, "items_moved": result.items_moved,
            "items_failed": result.items_failed, "duration_s": result.duration_s,
            "score_lines": [{"points": l.points, "reason": l.reason}
                            for l in result.score_lines],
            "output": json.loads(result.output_json) if result.output_json else None,
            "output_file": result.output_file, "events": events}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument("--address", required=True, help="HOST:PORT of picking-orchestrator")
    parser.add_argument("--task", required=True, type=pathlib.Path,
                        help="APC 2016 task file (JSON)")
    parser.add_argument("--time-limit-s", type=float, default=0.0,
                        help="task time budget; 0 means the rules' 900 s")
    parser.add_argument("--watch-timeout-s", type=float, default=3600.0,
                        help="deadline of the event stream")
    parser.add_argument("--result", type=pathlib.Path, help="write the outcome here as JSON")
    args = parser.parse_args(argv)
    try:
        task_json = args.task.read_text()
    except OSError as err:
        parser.error(f"cannot read the task file: {err}")

    pb, pb_grpc = load_contract()
    with grpc.insecure_channel(args.address) as channel:
        stub = pb_grpc.OrchestratorServiceStub(channel)
        try:
            started = stub.StartTask(pb.StartTaskRequest(task_json=task_json,
                                                         time_limit_s=args.time_limit_s),
                                     timeout=60)
            print(f"task {started.task_id}", flush=True)
            events = watch(pb, stub, started.task_id, args.watch_timeout_s)
            task = stub.GetTask(pb.GetTaskRequest(task_id=started.task_id), timeout=60)
        except grpc.RpcError as err:
            print(f"task_client: {err.code().name}: {err.details()}", file=sys.stderr)
            return 1

    outcome = summary(pb, task, events)
    if args.result:
        args.result.write_text(json.dumps(outcome, indent=2) + "\n")
    print(f"{outcome['state']}: score {outcome['score']}, {outcome['items_moved']} moved, "
          f"{outcome['items_failed']} failed, {outcome['duration_s']:.0f} s task clock")
    if task.error:
        print(f"error: {task.error}", file=sys.stderr)
    return 0 if task.state == pb.TASK_STATE_SUCCEEDED else 1


if __name__ == "__main__":
    sys.exit(main())
