// Gripper core benchmarks: the line protocol's encode/decode, one query round trip over a
// pseudo-terminal to the fake micro controller, and one keep-vertical control step.
#include <benchmark/benchmark.h>

#include <cmath>
#include <memory>

#include "services/gripper/core/keep_vertical.h"
#include "services/gripper/core/serial_link.h"
#include "services/gripper/core/serial_protocol.h"
#include "services/gripper/core/testing/fake_micro_controller.h"

namespace picking::gripper {
namespace {

void BM_TelemetryEncodeDecode(benchmark::State& state) {
  serial::Telemetry t;
  t.vacuum_kpa = 27.4;
  t.gravity_head_m_s2 = Eigen::Vector3d(0.01, 0.12, 9.806);
  t.joint_deg = -3.5;
  t.mode = JointMode::kKeepVertical;
  t.relay_on = true;
  std::uint32_t seq = 0;
  for (auto _ : state) {
    const std::string line = serial::EncodeLine(serial::OkBody(seq++ & 0xffff, FormatTelemetry(t)));
    const auto body = serial::DecodeLine(std::string_view(line).substr(0, line.size() - 1));
    const auto reply = serial::ParseReply(*body);
    benchmark::DoNotOptimize(serial::ParseTelemetry(reply->fields));
  }
}
BENCHMARK(BM_TelemetryEncodeDecode);

void BM_QueryRoundTripOverPty(benchmark::State& state) {
  testing::FakeMicroController fake;
  const std::string device = fake.device_path();
  serial::SerialLink link([device] { return serial::OpenSerialPort(device, 115200); }, device);
  for (auto _ : state) {
    benchmark::DoNotOptimize(link.Transact("Q"));
  }
  state.counters["retries"] = static_cast<double>(link.stats().retries);
}
BENCHMARK(BM_QueryRoundTripOverPty)->UseRealTime();

void BM_KeepVerticalStep(benchmark::State& state) {
  KeepVerticalController controller;
  double q = 0.0;
  const Eigen::Vector3d g_tool(0.0, 9.80665 * std::sin(0.4), 9.80665 * std::cos(0.4));
  for (auto _ : state) {
    q = controller.Step(GravityInHead(g_tool, q), q, 0.01).command_rad;
    benchmark::DoNotOptimize(q);
  }
}
BENCHMARK(BM_KeepVerticalStep);

}  // namespace
}  // namespace picking::gripper

BENCHMARK_MAIN();
