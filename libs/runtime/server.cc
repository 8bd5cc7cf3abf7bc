#include "libs/runtime/server.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/generic/async_generic_service.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/support/server_interceptor.h>
#include <pthread.h>
#include <signal.h>

#include <atomic>
#include <condition_variable>
#include <cstdio>
#include <iostream>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string_view>

#include "libs/runtime/log.h"
#include "libs/runtime/reflection_v1.h"
#include "libs/runtime/status.h"
#include "libs/runtime/tls.h"

namespace picking::runtime {
namespace {

std::mutex g_shutdown_mutex;
std::condition_variable g_shutdown_cv;
std::atomic<bool> g_shutting_down{false};

// Calls between their arrival and their end, counted by the interceptor below, so that a
// stop waits for real work only: an idle client connection must not hold the process for
// the whole grace period.
std::mutex g_calls_mutex;
std::condition_variable g_calls_cv;
int g_calls_in_flight = 0;

void CallStarted() {
  std::lock_guard<std::mutex> lock(g_calls_mutex);
  ++g_calls_in_flight;
}

void CallEnded() {
  {
    std::lock_guard<std::mutex> lock(g_calls_mutex);
    --g_calls_in_flight;
  }
  g_calls_cv.notify_all();
}

// Answers calls to methods no registered service has. gRPC's own answer is UNIMPLEMENTED
// with an empty message, which leaves a client guessing between a typo, a wrong port and
// an older server.
class UnknownMethodService final : public grpc::CallbackGenericService {
 public:
  explicit UnknownMethodService(const std::vector<std::string>& services) {
    for (const auto& name : services) served_ += (served_.empty() ? "" : ", ") + name;
  }

  grpc::ServerGenericBidiReactor* CreateReactor(
      grpc::GenericCallbackServerContext* context) override {
    class Reactor final : public grpc::ServerGenericBidiReactor {
     public:
      explicit Reactor(grpc::Status status) { Finish(status); }
      void OnDone() override { delete this; }
    };
    return new Reactor(grpc::Status(grpc::StatusCode::UNIMPLEMENTED,
                                    "no method " + CutMessage(context->method(), 120) +
                                        " on this server; it serves " + served_ +
                                        " (and grpc.health.v1.Health, server reflection)"));
  }

 private:
  std::string served_;
};

void SignalShutdown() {
  {
    std::lock_guard<std::mutex> lock(g_shutdown_mutex);
    g_shutting_down = true;
  }
  g_shutdown_cv.notify_all();
}

// Logs one line per finished call: method, status code, duration. Health and reflection
// calls are logged at debug level so that probes do not flood the log.
class CallLogInterceptor final : public grpc::experimental::Interceptor {
 public:
  explicit CallLogInterceptor(grpc::experimental::ServerRpcInfo* info)
      : method_(info->method() ? info->method() : "?"), start_(std::chrono::steady_clock::now()) {
    CallStarted();
  }
  ~CallLogInterceptor() override { CallEnded(); }

  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(
            grpc::experimental::InterceptionHookPoints::PRE_SEND_STATUS)) {
      const grpc::Status status = methods->GetSendStatus();
      const double ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start_)
              .count();
      const bool probe = method_.rfind("/grpc.", 0) == 0;
      const LogLevel level = probe         ? LogLevel::kDebug
                             : status.ok() ? LogLevel::kInfo
                                           : LogLevel::kWarning;
      char dur[32];
      std::snprintf(dur, sizeof(dur), "%.3f", ms);
      if (status.ok()) {
        Log(level, "rpc", {{"method", method_}, {"code", "OK"}, {"duration_ms", dur}});
      } else {
        Log(level, "rpc",
            {{"method", method_},
             {"code", StatusCodeName(status.error_code())},
             {"duration_ms", dur},
             {"error", status.error_message()}});
      }
    }
    methods->Proceed();
  }

 private:
  std::string method_;
  std::chrono::steady_clock::time_point start_;
};

class CallLogInterceptorFactory final
    : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  grpc::experimental::Interceptor* CreateServerInterceptor(
      grpc::experimental::ServerRpcInfo* info) override {
    return new CallLogInterceptor(info);
  }
};

void PrintHelp(const ServerSpec& spec) {
  std::cout << spec.program << ": " << spec.description << "\n\n"
            << "usage: " << spec.program << " [--listen=HOST:PORT] [--config=FILE] "
            << "[--key=value ...]\n\n"
            << "  --listen=HOST:PORT    address to serve on; port 0 picks a free port (default "
            << spec.default_listen << ")\n"
            << "  --config=FILE         YAML settings; --key=value flags override them\n"
            << "  --log-level=LEVEL     debug, info, warning or error (default info)\n"
            << "  --shutdown-grace-s=S  time in-flight calls get after SIGTERM (default 5)\n"
            << "  --max-message-mb=N    largest gRPC message (default 64)\n";
  std::cout
      << "  --tls.cert=FILE       PEM certificate this server presents, also to the servers\n"
      << "                        it calls; with --tls.key it serves TLS (default plaintext)\n"
      << "  --tls.key=FILE        PEM private key of --tls.cert\n"
      << "  --tls.ca=FILE         PEM CA certificate(s): clients must present a certificate\n"
      << "                        signed by them (mutual TLS), and the servers this one\n"
      << "                        calls must be signed by them\n"
      << "  --tls.server_name=N   (servers that call others) name expected in their\n"
      << "                        certificates instead of the address's host\n";
  if (!spec.settings_help.empty()) {
    std::cout << "\nsettings:\n";
    for (const auto& line : spec.settings_help) std::cout << "  " << line << "\n";
  }
}

const char* SecurityName(const TlsFiles& tls) {
  if (!tls.any()) return "plaintext";
  return tls.ca_path.empty() ? "tls" : "mutual-tls";
}

struct ParsedFlags {
  std::string listen;
  std::string config_path;
  std::string log_level = "info";
  double grace_s = 5.0;
  int max_message_mb = 64;
  bool help = false;
  std::vector<std::pair<std::string, std::string>> overrides;
};

ParsedFlags ParseFlags(int argc, char** argv, const ServerSpec& spec) {
  ParsedFlags flags;
  flags.listen = spec.default_listen;
  for (int i = 1; i < argc; ++i) {
    std::string arg = argv[i];
    if (arg == "--help" || arg == "-h") {
      flags.help = true;
      continue;
    }
    if (arg.rfind("--", 0) != 0) {
      throw std::invalid_argument("unexpected argument '" + arg + "' (flags are --key=value)");
    }
    const auto eq = arg.find('=');
    if (eq == std::string::npos) {
      throw std::invalid_argument("flag '" + arg + "' needs a value: " + arg + "=VALUE");
    }
    const std::string key = arg.substr(2, eq - 2);
    const std::string value = arg.substr(eq + 1);
    if (key == "listen") {
      flags.listen = value;
    } else if (key == "config") {
      flags.config_path = value;
    } else if (key == "log-level") {
      flags.log_level = value;
    } else if (key == "shutdown-grace-s") {
      Config c;
      c.Set(key, value);
      flags.grace_s = c.GetDouble(key, 5.0);
      if (flags.grace_s < 0) throw std::invalid_argument("--shutdown-grace-s must be >= 0");
    } else if (key == "max-message-mb") {
      Config c;
      c.Set(key, value);
      const long long mb = c.GetInt(key, 64);
      if (mb < 4 || mb > 1024) {
        throw std::invalid_argument("--max-message-mb must be within [4, 1024]");
      }
      flags.max_message_mb = static_cast<int>(mb);
    } else {
      flags.overrides.emplace_back(key, value);
    }
  }
  const auto colon = flags.listen.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == flags.listen.size()) {
    throw std::invalid_argument("--listen must be HOST:PORT, got '" + flags.listen + "'");
  }
  return flags;
}

}  // namespace

void ServiceSet::Add(std::shared_ptr<grpc::Service> service, std::string full_name) {
  services.push_back(std::move(service));
  full_names.push_back(std::move(full_name));
}

bool ShuttingDown() { return g_shutting_down.load(); }

bool WaitForShutdown(std::chrono::milliseconds timeout) {
  std::unique_lock<std::mutex> lock(g_shutdown_mutex);
  g_shutdown_cv.wait_for(lock, timeout, [] { return g_shutting_down.load(); });
  return g_shutting_down.load();
}

namespace {

// Blocks the stop signals in every thread (gRPC's included, which inherit this mask) so
// that only the sigwait of ServeUntilStopped receives them.
sigset_t BlockStopSignals() {
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGTERM);
  sigaddset(&stop_signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);
  return stop_signals;
}

// The service's settings: the --config file, then the --key=value overrides.
Config ConfigFrom(const ParsedFlags& flags) {
  Config config;
  if (!flags.config_path.empty()) config = Config::FromYamlFile(flags.config_path);
  for (const auto& [key, value] : flags.overrides) config.Set(key, value);
  return config;
}

// Builds the services and the server credentials; an exit status when they cannot be.
std::optional<int> BuildServices(const ServerSpec& spec, const Config& config, ServiceSet* set,
                                 std::shared_ptr<grpc::ServerCredentials>* credentials,
                                 TlsFiles* tls) {
  try {
    *tls = TlsFilesFromConfig(config);
    *credentials = ServerCredentialsFor(*tls);
    *set = spec.build(config);
    const auto unused = config.UnusedKeys();
    if (!unused.empty()) {
      std::string list;
      for (const auto& k : unused) list += (list.empty() ? "" : ", ") + k;
      throw std::invalid_argument("unknown setting(s): " + list);
    }
  } catch (const std::invalid_argument& e) {
    LogError("bad configuration", {{"error", e.what()}});
    std::cerr << spec.program << ": " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    LogError("cannot start", {{"error", e.what()}});
    std::cerr << spec.program << ": " << e.what() << "\n";
    return 1;
  }
  return std::nullopt;
}

// Waits for SIGTERM or SIGINT, lets in-flight calls finish within the grace period (long
// handlers see ShuttingDown() and end early), then shuts down with a short deadline that
// also closes idle client connections.
void ServeUntilStopped(grpc::Server* server, const sigset_t& stop_signals, double grace_s) {
  int signal_number = 0;
  sigwait(&stop_signals, &signal_number);
  LogInfo("stopping", {{"signal", signal_number == SIGTERM ? "SIGTERM" : "SIGINT"}});
  SignalShutdown();
  server->GetHealthCheckService()->SetServingStatus(false);
  {
    std::unique_lock<std::mutex> lock(g_calls_mutex);
    const bool drained = g_calls_cv.wait_for(
        lock, std::chrono::milliseconds(static_cast<long long>(grace_s * 1000.0)),
        [] { return g_calls_in_flight == 0; });
    if (!drained) {
      LogWarning("grace period over, cancelling calls",
                 {{"in_flight", std::to_string(g_calls_in_flight)}});
    }
  }
  server->Shutdown(std::chrono::system_clock::now() + std::chrono::milliseconds(200));
  server->Wait();
}

}  // namespace

int RunServerMain(int argc, char** argv, const ServerSpec& spec) {
  const sigset_t stop_signals = BlockStopSignals();
  ParsedFlags flags;
  Config config;
  try {
    flags = ParseFlags(argc, argv, spec);
    if (flags.help) {
      PrintHelp(spec);
      return 0;
    }
    ConfigureLogging(spec.service, ParseLogLevel(flags.log_level));
    config = ConfigFrom(flags);
  } catch (const std::exception& e) {
    std::cerr << spec.program << ": " << e.what() << "\n(see " << spec.program << " --help)\n";
    return 2;
  }
  ServiceSet set;
  std::shared_ptr<grpc::ServerCredentials> credentials;
  TlsFiles tls;
  if (const auto status = BuildServices(spec, config, &set, &credentials, &tls)) return *status;

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  AddReflectionV1(builder);
  int bound_port = 0;
  builder.AddListeningPort(flags.listen, credentials, &bound_port);
  const int max_bytes = flags.max_message_mb * 1024 * 1024;
  builder.SetMaxReceiveMessageSize(max_bytes);
  builder.SetMaxSendMessageSize(max_bytes);
  for (auto& s : set.services) builder.RegisterService(s.get());
  UnknownMethodService unknown_methods(set.full_names);
  builder.RegisterCallbackGenericService(&unknown_methods);
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> creators;
  creators.push_back(std::make_unique<CallLogInterceptorFactory>());
  builder.experimental().SetInterceptorCreators(std::move(creators));

  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (!server || bound_port == 0) {
    LogError("cannot listen", {{"address", flags.listen}});
    std::cerr << spec.program << ": cannot listen on " << flags.listen << "\n";
    return 1;
  }
  auto* health = server->GetHealthCheckService();
  health->SetServingStatus("", true);
  for (const auto& name : set.full_names) health->SetServingStatus(name, true);

  const std::string host = flags.listen.substr(0, flags.listen.rfind(':'));
  const std::string bound = host + ":" + std::to_string(bound_port);
  std::printf("listening on %s\n", bound.c_str());
  std::fflush(stdout);
  LogInfo("serving",
          {{"address", bound}, {"program", spec.program}, {"security", SecurityName(tls)}});

  ServeUntilStopped(server.get(), stop_signals, flags.grace_s);
  if (set.on_shutdown) {
    try {
      set.on_shutdown();
    } catch (const std::exception& e) {
      LogError("shutdown hook failed", {{"error", e.what()}});
      return 1;
    }
  }
  LogInfo("stopped");
  return 0;
}

}  // namespace picking::runtime
