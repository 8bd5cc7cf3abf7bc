#!/usr/bin/python3
"""Runs an example client (Python or Node.js) through a short task on a whole simulated cell.

And checks the client's refusals against an orchestrator alone: a malformed task file and
a task whose services are down both end with exit status 1 and the orchestrator's status.

scripts/run.sh starts every server of the build on free ports and runs the client in place
of `picking run`; the task picks the tissue box of pick_layout_1. The client's outcome file,
its printed lines and run.sh's copy of the APC output file must all tell the same story: the
task succeeded, the tissue box was placed in the tote, and the score counts it.

Usage (CTest does this): task_client_test.py python|node BIN_DIR WORK_DIR
The Node.js client's packages are installed with `npm ci` under WORK_DIR (never in the
source tree) from clients/node/package-lock.json.
"""

import filecmp
import json
import os
import pathlib
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import unittest

ROOT = pathlib.Path(__file__).resolve().parents[2]
TASK = ROOT / "tests" / "data" / "tasks" / "pick_layout_1_tissue_box.json"
ITEM = "kleenex_tissue_box"
LANGUAGE, BIN_DIR, WORK_DIR = (sys.argv.pop(1), pathlib.Path(sys.argv.pop(1)),
                               pathlib.Path(sys.argv.pop(1))) if len(sys.argv) > 3 else (
                                   "python", ROOT / "build" / "bin", ROOT / "build" / "clients")


def node_modules():
    """Installs the Node.js client's locked packages under WORK_DIR; returns the folder.

    A second run reuses them while the lock file is unchanged.
    """
    for tool in ("node", "npm"):
        if shutil.which(tool) is None:
            raise RuntimeError(f"{tool} is not on PATH (scripts/install-deps.sh installs it)")
    source = ROOT / "clients" / "node"
    target = WORK_DIR / "node"
    target.mkdir(parents=True, exist_ok=True)
    lock = target / "package-lock.json"
    installed = (target / "node_modules" / ".package-lock.json").exists()
    if not (installed and lock.exists() and filecmp.cmp(lock, source / "package-lock.json",
                                                        shallow=False)):
        for name in ("package.json", "package-lock.json"):
            shutil.copyfile(source / name, target / name)
        # No install scripts: the packages are pure JavaScript.
        subprocess.run(["npm", "ci", "--ignore-scripts", "--no-audit", "--no-fund"],
                       cwd=target, check=True, timeout=600)
    return target / "node_modules"


def client_command(language):
    """The client's command line for run.sh --client, and the environment it needs."""
    env = dict(os.environ)
    if language == "python":
        env["PICKING_PY_STUBS"] = str(WORK_DIR / "pystubs")
        program = ["/usr/bin/python3", str(ROOT / "clients" / "python" / "task_client.py")]
    elif language == "node":
        env["NODE_PATH"] = str(node_modules())
        program = ["node", str(ROOT / "clients" / "node" / "task_client.js")]
    else:
        raise SystemExit(f"unknown client language {language!r}")
    args = ["--address", "{address}", "--task", "{task}", "--result", "{out}/outcome.json"]
    return " ".join(program + args), env


def run_client(command, env, task_file, address):
    """Runs the client command outside run.sh, with the placeholders filled in."""
    with tempfile.TemporaryDirectory() as out:
        line = (command.replace("{address}", address).replace("{task}", str(task_file))
                .replace("{out}", out))
        return subprocess.run(line.split(" "), capture_output=True, text=True, env=env,
                              timeout=120)


class OrchestratorAlone:
    """picking-orchestrator on a free port, its peers on a port nothing listens on."""

    def __enter__(self):
        self.tasks = tempfile.TemporaryDirectory()
        nobody = "127.0.0.1:1"
        self.proc = subprocess.Popen(
            [str(BIN_DIR / "picking-orchestrator"), "--listen=127.0.0.1:0",
             f"--tasks_dir={self.tasks.name}", f"--scanner.address={nobody}",
             f"--detector.endpoints={nobody}", f"--planner.address={nobody}",
             f"--robot.address={nobody}", f"--gripper.address={nobody}"],
            stdout=subprocess.PIPE, text=True)
        ready, _, _ = select.select([self.proc.stdout], [], [], 60)
        line = self.proc.stdout.readline().strip() if ready else ""
        if not line.startswith("listening on "):
            self.proc.kill()
            raise RuntimeError(f"picking-orchestrator did not report its port: {line!r}")
        self.address = line[len("listening on "):]
        return self

    def __exit__(self, *exc):
        self.proc.send_signal(signal.SIGTERM)
        self.exit_code = self.proc.wait(timeout=30)
        self.proc.stdout.close()
        self.tasks.cleanup()


class TaskClientRefusalTest(unittest.TestCase):
    def test_a_malformed_task_file_is_refused(self):
        command, env = client_command(LANGUAGE)
        with tempfile.NamedTemporaryFile("w", suffix=".json") as bad, OrchestratorAlone() as orch:
            bad.write('{"bin_contents": ')
            bad.flush()
            result = run_client(command, env, bad.name, orch.address)
        self.assertEqual(result.returncode, 1, result.stdout + result.stderr)
        self.assertIn("INVALID_ARGUMENT", result.stderr)
        self.assertIn("malformed JSON", result.stderr)
        self.assertEqual(orch.exit_code, 0)

    def test_a_task_whose_services_are_down_is_unavailable(self):
        command, env = client_command(LANGUAGE)
        with OrchestratorAlone() as orch:
            result = run_client(command, env, TASK, orch.address)
        self.assertEqual(result.returncode, 1, result.stdout + result.stderr)
        self.assertIn("UNAVAILABLE", result.stderr)
        self.assertEqual(orch.exit_code, 0)


class TaskClientTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        command, env = client_command(LANGUAGE)
        cls.tmp = tempfile.TemporaryDirectory()
        cls.out = pathlib.Path(cls.tmp.name) / "run"
        cls.result = subprocess.run(
            [str(ROOT / "scripts" / "run.sh"), "--bin", str(BIN_DIR), "--task", str(TASK),
             "--out", str(cls.out), "--time-scale", "20", "--detector-budget-scale", "10",
             "--client", command],
            capture_output=True, text=True, env=env, timeout=840)
        sys.stdout.write(cls.result.stdout)
        sys.stderr.write(cls.result.stderr)
        outcome = cls.out / "outcome.json"
        cls.outcome = json.loads(outcome.read_text()) if outcome.exists() else None

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def setUp(self):
        if self.outcome is None:
            self.fail(f"the client wrote no outcome file (run.sh exit {self.result.returncode})")

    def test_the_task_succeeded_and_the_client_said_so(self):
        self.assertEqual(self.result.returncode, 0, self.result.stderr)
        self.assertEqual(self.outcome["state"], "TASK_STATE_SUCCEEDED", self.outcome["error"])
        self.assertIn(f"TASK_STATE_SUCCEEDED: score {self.outcome['score']}, 1 moved, 0 failed",
                      self.result.stdout)

    def test_the_events_arrived_in_order_one_line_each(self):
        events = self.outcome["events"]
        self.assertEqual([e["sequence"] for e in events], list(range(len(events))))
        self.assertTrue(all(e["state"] == "TASK_STATE_RUNNING" for e in events[:-1]))
        self.assertEqual(events[-1]["state"], "TASK_STATE_SUCCEEDED")
        lines = [l for l in self.result.stdout.splitlines() if l.startswith("[")]
        self.assertEqual(len(lines), len(events))
        for line, event in zip(lines, events):
            self.assertIn(f"#{event['sequence']} {event['items_done']}/{event['items_total']} ",
                          line)

    def test_the_events_tell_the_pick_of_the_item(self):
        steps = [e["step"] for e in self.outcome["events"] if e["item"] == ITEM and e["ok"]]
        for step in ("STEP_SCAN", "STEP_DETECT", "STEP_PLAN", "STEP_GRASP", "STEP_PLACE"):
            self.assertIn(step, steps)
        self.assertLess(steps.index("STEP_GRASP"), len(steps) - 1 - steps[::-1].index(
            "STEP_PLACE"))
        # The place that counts the item done is the last step of the item.
        places = [e for e in self.outcome["events"] if e["item"] == ITEM
                  and e["step"] == "STEP_PLACE"]
        self.assertEqual(places[-1]["items_done"], 1)
        self.assertTrue(places[-1]["ok"])
        self.assertEqual(self.outcome["events"][-1]["items_done"], 1)

    def test_the_output_file_has_the_item_in_the_tote(self):
        self.assertEqual(self.outcome["items_moved"], 1)
        self.assertEqual(self.outcome["output"]["tote_contents"], [ITEM])
        self.assertNotIn(ITEM, self.outcome["output"]["bin_contents"]["bin_A"])
        # run.sh's copy of the orchestrator's output file says the same.
        written = json.loads((self.out / "output.json").read_text())
        self.assertEqual(written, self.outcome["output"])

    def test_the_score_counts_the_pick(self):
        self.assertGreater(self.outcome["score"], 0)
        self.assertEqual(sum(l["points"] for l in self.outcome["score_lines"]),
                         self.outcome["score"])


if __name__ == "__main__":
    unittest.main(verbosity=2)
