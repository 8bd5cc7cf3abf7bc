#!/usr/bin/python3
"""Runs the Python client example against a real picking-planner server.

Usage (CTest does this): python_client_test.py BIN_DIR
"""

import math
import os
import pathlib
import select
import signal
import subprocess
import sys
import tempfile
import unittest

import grpc
from google.protobuf import descriptor_pb2

ROOT = pathlib.Path(__file__).resolve().parents[2]
CLIENT = ROOT / "clients" / "python" / "example_client.py"
sys.path.insert(0, str(CLIENT.parent))
import picking_stubs  # noqa: E402  (found through the path set just above)
BIN_DIR = pathlib.Path(sys.argv.pop(1)) if len(sys.argv) > 1 else ROOT / "build" / "bin"


class PlannerServer:
    """Starts picking-planner on a free port and reads the port it reports."""

    def __enter__(self):
        self.proc = subprocess.Popen([str(BIN_DIR / "picking-planner"), "--listen=127.0.0.1:0"],
                                     stdout=subprocess.PIPE, text=True)
        ready, _, _ = select.select([self.proc.stdout], [], [], 60)
        if not ready:
            self.proc.kill()
            raise RuntimeError("picking-planner did not report its port")
        line = self.proc.stdout.readline().strip()
        if not line.startswith("listening on "):
            self.proc.kill()
            raise RuntimeError(f"unexpected first line: {line!r}")
        self.address = line[len("listening on "):]
        return self

    def __exit__(self, *exc):
        self.proc.send_signal(signal.SIGTERM)
        self.exit_code = self.proc.wait(timeout=30)
        self.proc.stdout.close()


def run_client(address, *extra):
    env = dict(os.environ)
    env["PICKING_PY_STUBS"] = STUB_DIR
    return subprocess.run(["/usr/bin/python3", str(CLIENT), "--address", address, *extra],
                          capture_output=True, text=True, timeout=120, env=env)


class PythonClientTest(unittest.TestCase):
    def test_health_and_forward_kinematics(self):
        with PlannerServer() as server:
            result = run_client(server.address, "--joints", "0,0,0,0,0,0")
        self.assertEqual(result.returncode, 0, result.stderr)
        self.assertIn("health (server): SERVING", result.stdout)
        self.assertIn("health picking.planner.v1.PlannerService: SERVING", result.stdout)
        # UR10 factory DH chain at zero joints: x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
        self.assertIn("X_base_tool position_m: -1.1843 -0.2561 0.0116", result.stdout)
        # The suction cup's lip: the bundled cell's tool centre point, 0.35 m from the flange.
        positions = {}
        for line in result.stdout.splitlines():
            name, _, values = line.partition(" position_m: ")
            if values:
                positions[name] = [float(v) for v in values.split()]
        self.assertIn("X_base_tcp", positions, result.stdout)
        self.assertAlmostEqual(math.dist(positions["X_base_tool"], positions["X_base_tcp"]),
                               0.35, places=3)
        self.assertEqual(server.exit_code, 0)

    def test_bad_request_reports_invalid_argument(self):
        with PlannerServer() as server:
            result = run_client(server.address, "--joints", "0,0,0,0,0")
        self.assertEqual(result.returncode, 1)
        self.assertIn("INVALID_ARGUMENT", result.stderr)
        self.assertIn("6", result.stderr)


    def test_reflection_v1_from_python(self):
        # grpcio's client, not the C++ one of the other tests: the v1 service speaks the
        # wire format other languages' tools expect.
        os.environ["PICKING_PY_STUBS"] = STUB_DIR
        pb = picking_stubs.load(picking_stubs.REFLECTION_MODULE + ".reflection_pb2")
        pb_grpc = picking_stubs.load(picking_stubs.REFLECTION_MODULE + ".reflection_pb2_grpc")
        # Two questions answered by one file, on one stream: each answer holds it.
        requests = [pb.ServerReflectionRequest(list_services=""),
                    pb.ServerReflectionRequest(file_containing_symbol="grpc.health.v1.Health"),
                    pb.ServerReflectionRequest(
                        file_containing_symbol="grpc.health.v1.HealthCheckResponse")]
        with PlannerServer() as server, grpc.insecure_channel(server.address) as channel:
            stub = pb_grpc.ServerReflectionStub(channel)
            listed, health, again = list(stub.ServerReflectionInfo(iter(requests), timeout=30))
        names = [s.name for s in listed.list_services_response.service]
        for name in ("picking.planner.v1.PlannerService", "grpc.health.v1.Health",
                     "grpc.reflection.v1.ServerReflection"):
            self.assertIn(name, names)
        files = [descriptor_pb2.FileDescriptorProto.FromString(b)
                 for b in health.file_descriptor_response.file_descriptor_proto]
        self.assertEqual([f.name for f in files], ["grpc/health/v1/health.proto"])
        self.assertEqual([s.name for s in files[0].service], ["Health"])
        self.assertEqual(again.file_descriptor_response.file_descriptor_proto,
                         health.file_descriptor_response.file_descriptor_proto)
        self.assertEqual(server.exit_code, 0)


if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as tmp:
        STUB_DIR = tmp
        unittest.main(verbosity=2)
