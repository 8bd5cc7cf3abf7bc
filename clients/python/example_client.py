#!/usr/bin/python3
"""Example: talk to a picking service from Python.

Checks the server's health (grpc.health.v1) and asks the planner for the poses of the UR10's
tool flange (X_base_tool) and of the gripper's tool centre point, the suction cup's lip
(X_base_tcp), at a joint configuration (picking.planner.v1.PlannerService/ComputeFk).

    /usr/bin/python3 clients/python/example_client.py --address 127.0.0.1:50053 \
        --joints 0,-1.57,1.57,-1.57,-1.57,0

Exit status: 0 on success, 1 when the server is not serving or the call fails.
"""

import argparse
import sys

import grpc

import picking_stubs


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument("--address", required=True, help="HOST:PORT of picking-planner")
    parser.add_argument("--joints", default="0,-1.5708,1.5708,-1.5708,-1.5708,0",
                        help="six joint positions in radians, comma-separated")
    parser.add_argument("--timeout-s", type=float, default=10.0)
    args = parser.parse_args(argv)

    health_pb2 = picking_stubs.load(picking_stubs.HEALTH_MODULE + ".health_pb2")
    health_grpc = picking_stubs.load(picking_stubs.HEALTH_MODULE + ".health_pb2_grpc")
    robot_types = picking_stubs.load("picking.common.v1.robot_types_pb2")
    planner_pb2 = picking_stubs.load("picking.planner.v1.planner_pb2")
    planner_grpc = picking_stubs.load("picking.planner.v1.planner_pb2_grpc")

    joints = [float(v) for v in args.joints.split(",")]
    with grpc.insecure_channel(args.address) as channel:
        health = health_grpc.HealthStub(channel)
        for service in ("", "picking.planner.v1.PlannerService"):
            reply = health.Check(health_pb2.HealthCheckRequest(service=service),
                                 timeout=args.timeout_s)
            status = health_pb2.HealthCheckResponse.ServingStatus.Name(reply.status)
            print(f"health {service or '(server)'}: {status}")
            if reply.status != health_pb2.HealthCheckResponse.SERVING:
                return 1

        planner = planner_grpc.PlannerServiceStub(channel)
        request = planner_pb2.ComputeFkRequest(
            joints=robot_types.JointPositions(positions_rad=joints))
        try:
            fk = planner.ComputeFk(request, timeout=args.timeout_s)
        except grpc.RpcError as err:
            print(f"ComputeFk failed: {err.code().name}: {err.details()}", file=sys.stderr)
            return 1
        for name, pose in (("X_base_tool", fk.X_base_tool), ("X_base_tcp", fk.X_base_tcp)):
            p, q = pose.position, pose.orientation
            print(f"{name} position_m: {p.x:.4f} {p.y:.4f} {p.z:.4f}")
            print(f"{name} orientation_wxyz: {q.w:.4f} {q.x:.4f} {q.y:.4f} {q.z:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
