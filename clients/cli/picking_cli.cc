// picking: runs and watches APC tasks on the cell through the orchestrator.
//
//   picking run TASK.json [--time-limit S] [--ease item,item,...] [--resume ID]
//   picking watch ID      picking status [ID]      picking list
//   picking cancel ID     picking score ID
//   picking health [--service NAME]     (any picking server's grpc.health.v1 answer)
//   picking call ADDRESS SERVICE/METHOD ['JSON']   any method of any server, by reflection
// Options: --address HOST:PORT (default $PICKING_ORCHESTRATOR or localhost:50050), --json (one
// JSON object per event or answer instead of the progress display); for run: --wait S (keep
// asking an orchestrator that is not up yet, or whose peers are not, for up to S seconds); for
// run and watch: --out DIR (write the output file and the score there, from the answer, not
// the orchestrator's disk); --tls-ca FILE (TLS: the CA the server's certificate must be signed
// by), --tls-cert FILE --tls-key FILE (the certificate shown to a server that requires one:
// mutual TLS), --tls-server-name NAME (the name checked in the server's certificate instead of
// the address's host).
// Exit codes: 0 the task succeeded (or the command did; for health: SERVING), 1 the task failed
// or was cancelled (health: not serving), 2 bad usage (for call also an unknown service or
// method, or a request that does not parse), 3 the orchestrator (or the called server) refused
// the request or could not be reached.
#include <grpcpp/create_channel.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "clients/cli/call.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "libs/runtime/channel.h"
#include "picking/orchestrator/v1/orchestrator.grpc.pb.h"

namespace {

namespace pb = ::picking::orchestrator::v1;

constexpr int kOk = 0, kTaskFailed = 1, kUsage = 2, kRpcError = 3;

struct Args {
  std::string command;
  std::vector<std::string> positional;
  std::string address;
  bool json = false;
  double time_limit_s = 0.0;
  std::vector<std::string> ease;
  std::string resume;
  double wait_s = 0.0;  ///< run: how long to keep trying an orchestrator that is not ready.
  std::string out_dir;  ///< run: where to write output.json and score.txt.
  std::string service;  ///< health: the service name to ask about ("" = the server).
  picking::runtime::TlsFiles tls;
  std::string tls_server_name;
};

int Usage(const std::string& error) {
  if (!error.empty()) std::cerr << "picking: " << error << "\n";
  std::cerr << "usage: picking run TASK.json [--time-limit S] [--ease a,b] [--resume ID]\n"
               "                           [--wait S] [--out DIR]\n"
               "       picking watch ID | status [ID] | list | cancel ID | score ID\n"
               "       picking health [--service NAME]\n"
               "       picking call ADDRESS SERVICE/METHOD ['JSON']\n"
               "options: --address HOST:PORT (default $PICKING_ORCHESTRATOR or "
               "localhost:50050), --json\n"
               "         --tls-ca FILE [--tls-cert FILE --tls-key FILE] [--tls-server-name N]\n";
  return kUsage;
}

std::vector<std::string> Split(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream in(text);
  for (std::string part; std::getline(in, part, ',');) {
    if (!part.empty()) out.push_back(part);
  }
  return out;
}

// Reads a number of seconds > 0 (and below a day: a larger value is a typo, not a wish).
bool ParseSeconds(const std::string& flag, const char* text, double* seconds, std::string* error) {
  char* end = nullptr;
  *seconds = std::strtod(text, &end);
  if (end == text || *end != '\0' || !(*seconds > 0.0) || !(*seconds <= 86400.0)) {
    *error = flag + ": expected seconds in (0, 86400], got '" + std::string(text) + "'";
    return false;
  }
  return true;
}

// Stores --tls-* options; false for an unknown one. Other options are left alone (true).
bool SetTlsOption(const std::string& option, const std::string& value, Args* args) {
  if (option.rfind("--tls-", 0) != 0) return true;
  if (option == "--tls-cert") {
    args->tls.cert_path = value;
  } else if (option == "--tls-key") {
    args->tls.key_path = value;
  } else if (option == "--tls-ca") {
    args->tls.ca_path = value;
  } else if (option == "--tls-server-name") {
    args->tls_server_name = value;
  } else {
    return false;
  }
  return true;
}

// Returns false on a malformed command line (with the reason in `error`).
bool Parse(int argc, char** argv, Args* args, std::string* error) {
  const char* env = std::getenv("PICKING_ORCHESTRATOR");
  args->address = env != nullptr && *env != '\0' ? env : "localhost:50050";
  args->tls.cert_name = "--tls-cert";
  args->tls.key_name = "--tls-key";
  args->tls.ca_name = "--tls-ca";
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](const char* name) -> const char* {
      if (i + 1 >= argc) {
        *error = std::string(name) + " needs a value";
        return nullptr;
      }
      return argv[++i];
    };
    if (a == "--json") {
      args->json = true;
    } else if (a == "--address" || a == "--time-limit" || a == "--ease" || a == "--resume" ||
               a == "--wait" || a == "--out" || a == "--service" || a.rfind("--tls-", 0) == 0) {
      const char* v = value(a.c_str());
      if (v == nullptr) return false;
      if (!SetTlsOption(a, v, args)) {
        *error = "unknown option " + a;
        return false;
      }
      if (a == "--address") args->address = v;
      if (a == "--ease") args->ease = Split(v);
      if (a == "--resume") args->resume = v;
      if (a == "--out") args->out_dir = v;
      if (a == "--service") args->service = v;
      if (a == "--time-limit" && !ParseSeconds(a, v, &args->time_limit_s, error)) return false;
      if (a == "--wait" && !ParseSeconds(a, v, &args->wait_s, error)) return false;
    } else if (a == "-h" || a == "--help") {
      *error = "";
      return false;
    } else if (a.rfind("--", 0) == 0) {
      *error = "unknown option " + a;
      return false;
    } else if (args->command.empty()) {
      args->command = a;
    } else {
      args->positional.push_back(a);
    }
  }
  if (args->command.empty()) {
    *error = "no command";
    return false;
  }
  return true;
}

const char* SecurityName(const picking::runtime::TlsFiles& tls) {
  if (!tls.any()) return "plaintext";
  return tls.cert_path.empty() ? "TLS" : "mutual TLS";
}

// UNAVAILABLE is also how a refused TLS handshake ends (a plaintext client, a missing or
// untrusted certificate), so it says how the connection was made and what TLS needs.
int RpcError(const Args& args, const std::string& what, const grpc::Status& status) {
  std::cerr << "picking: " << what << ": " << status.error_message() << " (code "
            << status.error_code() << ")\n";
  if (status.error_code() == grpc::StatusCode::UNAVAILABLE) {
    std::cerr << "picking: the orchestrator at " << args.address << " was called over "
              << SecurityName(args.tls)
              << "; an orchestrator serving TLS needs --tls-ca, one serving mutual TLS also "
                 "--tls-cert and --tls-key\n";
  }
  return kRpcError;
}

const char* StateName(pb::TaskState s) {
  switch (s) {
    case pb::TASK_STATE_RUNNING:
      return "running";
    case pb::TASK_STATE_SUCCEEDED:
      return "succeeded";
    case pb::TASK_STATE_FAILED:
      return "failed";
    case pb::TASK_STATE_CANCELLED:
      return "cancelled";
    default:
      return "unknown";
  }
}

std::string StepName(pb::Step step) {
  std::string name = pb::Step_Name(step);
  return step == pb::STEP_UNSPECIFIED ? "" : name.substr(5);
}

nlohmann::json EventJson(const pb::TaskEvent& e) {
  return {{"sequence", e.sequence()},
          {"time_s", e.time_s()},
          {"item", e.item()},
          {"step", StepName(e.step())},
          {"ok", e.step_ok()},
          {"message", e.message()},
          {"items_done", e.items_done()},
          {"items_total", e.items_total()},
          {"state", StateName(e.state())}};
}

nlohmann::json TaskJson(const pb::GetTaskResponse& t) {
  nlohmann::json j = {{"task_id", t.task_id()},
                      {"state", StateName(t.state())},
                      {"items_done", t.items_done()},
                      {"items_total", t.items_total()},
                      {"error", t.error()}};
  if (t.state() != pb::TASK_STATE_RUNNING) {
    j["score"] = t.result().score();
    j["items_moved"] = t.result().items_moved();
    j["duration_s"] = t.result().duration_s();
    j["output_file"] = t.result().output_file();
    j["report_file"] = t.result().report_file();
    j["score_lines"] = nlohmann::json::array();
    for (const auto& l : t.result().score_lines()) {
      j["score_lines"].push_back({{"points", l.points()}, {"reason", l.reason()}});
    }
  }
  return j;
}

// The live display: a line per finished item, and a progress bar kept on the last line.
class Display {
 public:
  explicit Display(double time_limit_s) : time_limit_s_(time_limit_s) {}
  void Show(const pb::TaskEvent& e) {
    // A line per finished attempt: placed (the event names where to) or failed.
    const bool item_line =
        !e.item().empty() &&
        (e.step() == pb::STEP_UNSPECIFIED ||
         (e.step() == pb::STEP_PLACE && e.to() != picking::common::v1::CONTAINER_UNSPECIFIED));
    if (e.state() != pb::TASK_STATE_RUNNING) {
      std::printf("\r\033[K%s: %s\n", StateName(e.state()), e.message().c_str());
      return;
    }
    if (item_line) {
      std::printf("\r\033[K%s %-36s %s\n", e.step_ok() ? "ok  " : "FAIL", e.item().c_str(),
                  e.message().c_str());
    }
    const int width = 24;
    const int filled = e.items_total() > 0 ? width * static_cast<int>(e.items_done()) /
                                                 static_cast<int>(e.items_total())
                                           : 0;
    std::printf("\r\033[K[%s%s] %u/%u  %-28.28s %-7s  %4.0f s left",
                std::string(filled, '#').c_str(), std::string(width - filled, '.').c_str(),
                e.items_done(), e.items_total(), e.item().c_str(), StepName(e.step()).c_str(),
                time_limit_s_ - e.time_s());
    std::fflush(stdout);
  }

 private:
  double time_limit_s_;
};

// Streams the task's events until it ends; its final state lands in `task`.
int Watch(pb::OrchestratorService::Stub& stub, const std::string& id, const Args& args,
          pb::GetTaskResponse* task) {
  grpc::ClientContext ctx;
  pb::WatchTaskRequest request;
  request.set_task_id(id);
  auto reader = stub.WatchTask(&ctx, request);
  Display display(args.time_limit_s > 0.0 ? args.time_limit_s : 900.0);
  pb::WatchTaskResponse response;
  pb::TaskState last = pb::TASK_STATE_RUNNING;
  while (reader->Read(&response)) {
    const pb::TaskEvent& event = response.event();
    if (args.json) {
      std::cout << EventJson(event).dump() << "\n" << std::flush;
    } else {
      display.Show(event);
    }
    last = event.state();
  }
  const grpc::Status status = reader->Finish();
  if (!status.ok()) return RpcError(args, "watch " + id, status);
  grpc::ClientContext get_ctx;
  pb::GetTaskRequest get;
  get.set_task_id(id);
  if (grpc::Status s = stub.GetTask(&get_ctx, get, task); !s.ok()) {
    return RpcError(args, "status", s);
  }
  if (args.json) {
    std::cout << TaskJson(*task).dump() << "\n";
  } else {
    std::printf("score %d, %u of %u items moved, %.0f s task clock\noutput: %s\nreport: %s\n",
                task->result().score(), task->result().items_moved(), task->items_total(),
                task->result().duration_s(), task->result().output_file().c_str(),
                task->result().report_file().c_str());
  }
  return last == pb::TASK_STATE_SUCCEEDED ? kOk : kTaskFailed;
}

// Starts the task. With --wait, an orchestrator that is not listening yet or whose peers are
// not (UNAVAILABLE) is asked again once a second until the wait is over, so that a one-shot
// task container can be started together with the cell.
grpc::Status StartTask(pb::OrchestratorService::Stub& stub, const pb::StartTaskRequest& request,
                       const Args& args, pb::StartTaskResponse* started) {
  const auto give_up = std::chrono::steady_clock::now() +
                       std::chrono::milliseconds(static_cast<long long>(args.wait_s * 1000.0));
  bool told = false;
  for (;;) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    const grpc::Status status = stub.StartTask(&ctx, request, started);
    if (status.error_code() != grpc::StatusCode::UNAVAILABLE ||
        std::chrono::steady_clock::now() >= give_up) {
      return status;
    }
    if (!told) {
      std::cerr << "picking: waiting up to " << args.wait_s
                << " s for the cell: " << status.error_message() << "\n";
      told = true;
    }
    std::this_thread::sleep_for(std::chrono::seconds(1));  // the retry pace
  }
}

// Writes what the task's answer holds to `dir`: output.json (the APC output file), score.txt
// (each scoring line and the total) and task.json (the final state).
int WriteOutputs(const std::string& dir, const pb::GetTaskResponse& task) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream out(std::filesystem::path(dir) / name);
    out << text;
    return static_cast<bool>(out.flush());
  };
  std::ostringstream score;
  for (const auto& l : task.result().score_lines())
    score << l.points() << "\t" << l.reason() << "\n";
  score << task.result().score() << "\ttotal\n";
  if (ec || !write("output.json", task.result().output_json()) ||
      !write("score.txt", score.str()) || !write("task.json", TaskJson(task).dump(2) + "\n")) {
    std::cerr << "picking: cannot write the results to " << dir << "\n";
    return kTaskFailed;
  }
  if (!task.result().output_json().empty()) std::printf("results written to %s\n", dir.c_str());
  return kOk;
}

// Watches the task to its end; with --out, writes its results there.
int WatchAndWrite(pb::OrchestratorService::Stub& stub, const std::string& id, const Args& args) {
  pb::GetTaskResponse task;
  const int code = Watch(stub, id, args, &task);
  if (code == kRpcError || args.out_dir.empty()) return code;
  const int written = WriteOutputs(args.out_dir, task);
  return written != kOk ? written : code;
}

int Run(pb::OrchestratorService::Stub& stub, const Args& args) {
  if (args.positional.size() != 1 && args.resume.empty()) return Usage("run needs a task file");
  pb::StartTaskRequest request;
  if (!args.positional.empty()) {
    std::ifstream in(args.positional[0]);
    if (!in) return Usage("cannot read " + args.positional[0]);
    std::stringstream text;
    text << in.rdbuf();
    request.set_task_json(text.str());
  }
  request.set_time_limit_s(args.time_limit_s);
  for (const auto& e : args.ease) request.add_ease_order(e);
  request.set_resume_task_id(args.resume);
  pb::StartTaskResponse started;
  if (grpc::Status s = StartTask(stub, request, args, &started); !s.ok()) {
    return RpcError(args, "run", s);
  }
  if (!args.json) std::printf("task %s\n", started.task_id().c_str());
  return WatchAndWrite(stub, started.task_id(), args);
}

// Asks any picking server's standard health service about itself or one of its services.
int Health(const std::shared_ptr<grpc::Channel>& channel, const Args& args) {
  auto stub = grpc::health::v1::Health::NewStub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  grpc::health::v1::HealthCheckRequest request;
  request.set_service(args.service);
  grpc::health::v1::HealthCheckResponse response;
  if (grpc::Status s = stub->Check(&ctx, request, &response); !s.ok()) {
    return RpcError(args, "health of " + args.address, s);
  }
  const std::string state =
      grpc::health::v1::HealthCheckResponse::ServingStatus_Name(response.status());
  if (args.json) {
    std::cout << nlohmann::json{{"address", args.address},
                                {"service", args.service},
                                {"status", state}}
                     .dump()
              << "\n";
  } else {
    std::printf("%s %s%s%s\n", args.address.c_str(), state.c_str(), args.service.empty() ? "" : " ",
                args.service.c_str());
  }
  return response.status() == grpc::health::v1::HealthCheckResponse::SERVING ? kOk : kTaskFailed;
}

int Status(pb::OrchestratorService::Stub& stub, const Args& args) {
  std::vector<pb::GetTaskResponse> tasks;
  if (args.positional.empty()) {
    grpc::ClientContext ctx;
    pb::ListTasksResponse list;
    if (grpc::Status s = stub.ListTasks(&ctx, {}, &list); !s.ok()) return RpcError(args, "list", s);
    tasks.assign(list.tasks().begin(), list.tasks().end());
    if (args.command == "status" && !tasks.empty()) tasks.resize(1);
  } else {
    grpc::ClientContext ctx;
    pb::GetTaskRequest request;
    request.set_task_id(args.positional[0]);
    pb::GetTaskResponse task;
    if (grpc::Status s = stub.GetTask(&ctx, request, &task); !s.ok())
      return RpcError(args, "status", s);
    tasks.push_back(task);
  }
  for (const auto& t : tasks) {
    if (args.json) {
      std::cout << TaskJson(t).dump() << "\n";
    } else if (args.command == "score") {
      for (const auto& l : t.result().score_lines())
        std::printf("%+4d  %s\n", l.points(), l.reason().c_str());
      std::printf("%4d  total\n", t.result().score());
    } else {
      std::printf("%-28s %-10s %u/%u items  score %d%s%s\n", t.task_id().c_str(),
                  StateName(t.state()), t.items_done(), t.items_total(), t.result().score(),
                  t.error().empty() ? "" : "  ", t.error().c_str());
    }
  }
  return kOk;
}

}  // namespace

int main(int argc, char** argv) {
  Args args;
  std::string error;
  if (!Parse(argc, argv, &args, &error)) return Usage(error);
  if (args.command == "call") {
    // The address is the called server's, not the orchestrator's: it comes first.
    const auto& p = args.positional;
    if (p.size() != 2 && p.size() != 3) return Usage("call needs ADDRESS SERVICE/METHOD ['JSON']");
    return picking::cli::Call(p[0], p[1], p.size() == 3 ? p[2] : "", std::cout, std::cerr);
  }
  std::shared_ptr<grpc::Channel> channel;
  try {
    channel =
        picking::runtime::ChannelFactory(args.tls, args.tls_server_name).Connect(args.address);
  } catch (const std::invalid_argument& e) {
    return Usage(e.what());
  }
  auto stub = pb::OrchestratorService::NewStub(channel);
  const auto& c = args.command;
  if (c == "run") return Run(*stub, args);
  if (c == "health") return Health(channel, args);
  if (c == "watch") {
    if (args.positional.size() != 1) return Usage("watch needs a task id");
    return WatchAndWrite(*stub, args.positional[0], args);
  }
  if (c == "status" || c == "list") return Status(*stub, args);
  if (c == "score") {
    if (args.positional.size() != 1) return Usage("score needs a task id");
    return Status(*stub, args);
  }
  if (c == "cancel") {
    if (args.positional.size() != 1) return Usage("cancel needs a task id");
    grpc::ClientContext ctx;
    pb::CancelTaskRequest request;
    request.set_task_id(args.positional[0]);
    pb::CancelTaskResponse response;
    if (grpc::Status s = stub->CancelTask(&ctx, request, &response); !s.ok()) {
      return RpcError(args, "cancel", s);
    }
    if (!args.json)
      std::printf("cancelling %s after its current step\n", args.positional[0].c_str());
    return kOk;
  }
  return Usage("unknown command '" + c + "'");
}
