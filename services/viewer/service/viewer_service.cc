#include "services/viewer/service/viewer_service.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <list>
#include <memory>
#include <mutex>
#include <regex>
#include <sstream>
#include <stdexcept>
#include <thread>

#include "libs/apc/catalogue.h"
#include "libs/runtime/channel.h"
#include "libs/runtime/log.h"
#include "libs/ur10/ur10_model.h"
#include "picking/orchestrator/v1/orchestrator.grpc.pb.h"
#include "services/viewer/service/followers.h"

// Last: it brings in <resolv.h>, whose _res macro breaks Eigen's headers included after it.
#include <httplib.h>

namespace picking::viewer {
namespace {

namespace fs = std::filesystem;

constexpr auto kStreamPoll = std::chrono::milliseconds(100);
constexpr double kKeepAliveS = 15.0;
constexpr std::size_t kHttpWorkers = 32;

std::string ContentType(const std::string& path) {
  const std::string ext = fs::path(path).extension().string();
  if (ext == ".html") return "text/html; charset=utf-8";
  if (ext == ".js") return "text/javascript; charset=utf-8";
  if (ext == ".css") return "text/css; charset=utf-8";
  if (ext == ".png") return "image/png";
  if (ext == ".svg") return "image/svg+xml";
  return "application/octet-stream";
}

// HOST:PORT, or throws naming the setting.
std::pair<std::string, int> SplitListen(const std::string& listen) {
  const auto colon = listen.rfind(':');
  if (colon == std::string::npos || colon == 0) {
    throw std::invalid_argument("setting 'http_listen': expected HOST:PORT, got '" + listen + "'");
  }
  int port = -1;
  try {
    port = std::stoi(listen.substr(colon + 1));
  } catch (const std::exception&) {
  }
  if (port < 0 || port > 65535) {
    throw std::invalid_argument("setting 'http_listen': bad port in '" + listen + "'");
  }
  return {listen.substr(0, colon), port};
}

bool ValidTaskId(const std::string& id) {
  static const std::regex kId("[A-Za-z0-9_.-]{0,128}");
  return std::regex_match(id, kId) && id.find("..") == std::string::npos;
}

std::string SseEvent(const std::string& name, const std::string& json) {
  return "event: " + name + "\ndata: " + json + "\n\n";
}

// The page's files: every regular file in `web_dir`, and the parts of three.js it loads.
std::map<std::string, std::string> StaticFiles(const ViewerSettings& settings) {
  std::map<std::string, std::string> files;
  if (!fs::is_directory(settings.web_dir)) {
    throw std::runtime_error("the page's folder '" + settings.web_dir + "' does not exist");
  }
  for (const auto& entry : fs::directory_iterator(settings.web_dir)) {
    if (entry.is_regular_file()) files["/" + entry.path().filename().string()] = entry.path();
  }
  if (files.count("/index.html") == 0) {
    throw std::runtime_error("no index.html in the page's folder '" + settings.web_dir + "'");
  }
  files["/"] = files["/index.html"];
  const std::string& three = settings.three_dir;
  const std::map<std::string, std::string> three_files = {
      {"/three/three.min.js", three + "/build/three.min.js"},
      {"/three/OrbitControls.js", three + "/examples/js/controls/OrbitControls.js"},
      {"/three/STLLoader.js", three + "/examples/js/loaders/STLLoader.js"},
      {"/three/PLYLoader.js", three + "/examples/js/loaders/PLYLoader.js"}};
  for (const auto& [url, path] : three_files) {
    if (!fs::exists(path)) {
      throw std::runtime_error("three.js is missing: '" + path +
                               "' (Debian's libjs-three; or set three_dir)");
    }
    files[url] = path;
  }
  return files;
}

ViewerModel LoadModel(const ViewerSettings& settings) {
  world::CellModel cell = world::LoadCellModel(world::ReadCellConfig(settings.cell_path));
  ur10::Ur10Kinematics kinematics(ur10::Ur10Model::Load(settings.data_dir + "/ur10"));
  world::ItemModelLibraryOptions options;
  options.shape_table_path = settings.data_dir + "/items/shapes.yaml";
  options.models_dir = settings.data_dir + "/models";
  auto items = std::make_shared<const world::ItemModelLibrary>(
      apc::Catalogue::FromCsvFile(settings.data_dir + "/apc2016/items/item_data.csv"), options);
  return ViewerModel(std::move(cell), std::move(kinematics), std::move(items));
}

/// The HTTP side: the page and its files, the cell, the tasks and each task's view, as one
/// snapshot (/api/view) or as a stream of changes (/api/stream, server-sent events).
class ViewerHttp final {
 public:
  ViewerHttp(ViewerSettings settings, std::shared_ptr<grpc::Channel> orchestrator,
             std::shared_ptr<grpc::Channel> robot)
      : settings_(std::move(settings)),
        model_(LoadModel(settings_)),
        static_files_(StaticFiles(settings_)),
        cell_json_(model_.CellJson().dump()),
        orchestrator_(std::move(orchestrator)),
        arm_(std::move(robot), model_, settings_.arm_rate_hz) {
    // Every open page holds a worker for its event stream: more than httplib's default.
    server_.new_task_queue = [] { return new httplib::ThreadPool(kHttpWorkers); };
    Routes();
  }

  ~ViewerHttp() { Stop(); }

  /// Binds and serves on a thread; returns the bound port.
  int Start() {
    const auto [host, port] = SplitListen(settings_.http_listen);
    const int bound = port == 0 ? server_.bind_to_any_port(host) : port;
    if (bound < 0 || (port != 0 && !server_.bind_to_port(host, port))) {
      throw std::runtime_error("cannot listen for HTTP on " + settings_.http_listen);
    }
    thread_ = std::thread([this] { server_.listen_after_bind(); });
    return bound;
  }

  void Stop() {
    if (stopping_.exchange(true)) return;
    arm_.store().WakeAll();
    server_.stop();
    if (thread_.joinable()) thread_.join();
    std::lock_guard<std::mutex> lock(mutex_);
    followers_.clear();
  }

 private:
  void Routes() {
    server_.Get("/api/cell", [this](const httplib::Request&, httplib::Response& res) {
      res.set_content(cell_json_, "application/json");
    });
    server_.Get("/api/tasks",
                [this](const httplib::Request&, httplib::Response& res) { Tasks(res); });
    server_.Get("/api/view", [this](const httplib::Request& req, httplib::Response& res) {
      if (auto follower = FollowerFor(req, res)) {
        res.set_content(View(*follower).dump(), "application/json");
      }
    });
    server_.Get("/api/stream", [this](const httplib::Request& req, httplib::Response& res) {
      if (auto follower = FollowerFor(req, res)) Stream(std::move(follower), res);
    });
    server_.Get("/healthz", [](const httplib::Request&, httplib::Response& res) {
      res.set_content("ok\n", "text/plain");
    });
    server_.Get(R"(/files/.*)", [this](const httplib::Request& req, httplib::Response& res) {
      File(req.path, res);
    });
    server_.Get(R"(/.*)", [this](const httplib::Request& req, httplib::Response& res) {
      StaticFile(req.path, res);
    });
  }

  static void Error(httplib::Response& res, int status, const std::string& message) {
    res.status = status;
    res.set_content(nlohmann::json({{"error", message}}).dump(), "application/json");
  }

  void StaticFile(const std::string& path, httplib::Response& res) {
    const auto it = static_files_.find(path);
    if (it == static_files_.end()) return Error(res, 404, "no such page: " + path);
    try {
      res.set_content(ReadBytes(it->second), ContentType(it->second));
    } catch (const std::exception& e) {
      Error(res, 500, e.what());
    }
  }

  void File(const std::string& path, httplib::Response& res) {
    try {
      const std::optional<ServedFile> file = model_.File(path);
      if (!file) return Error(res, 404, "no such file: " + path);
      res.set_header("Cache-Control", "max-age=3600");
      res.set_content(file->bytes, file->content_type);
    } catch (const std::exception& e) {
      Error(res, 500, std::string("cannot build ") + path + ": " + e.what());
    }
  }

  void Tasks(httplib::Response& res);
  std::shared_ptr<TaskFollower> FollowerFor(const httplib::Request& req, httplib::Response& res);
  nlohmann::json View(TaskFollower& follower);
  nlohmann::json Status(TaskFollower& follower);
  void Stream(std::shared_ptr<TaskFollower> follower, httplib::Response& res);

  ViewerSettings settings_;
  ViewerModel model_;
  std::map<std::string, std::string> static_files_;
  std::string cell_json_;
  std::shared_ptr<grpc::Channel> orchestrator_;
  ArmFollower arm_;
  httplib::Server server_;
  std::thread thread_;
  std::atomic<bool> stopping_{false};
  std::mutex mutex_;
  /// Followed tasks, most recently asked for first; "" follows the newest task.
  std::list<std::pair<std::string, std::shared_ptr<TaskFollower>>> followers_;
};

void ViewerHttp::Tasks(httplib::Response& res) {
  auto stub = orchestrator::v1::OrchestratorService::NewStub(orchestrator_);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(3));
  orchestrator::v1::ListTasksResponse list;
  const grpc::Status status = stub->ListTasks(&ctx, {}, &list);
  if (!status.ok()) return Error(res, 503, "orchestrator: " + status.error_message());
  nlohmann::json tasks = nlohmann::json::array();
  for (const auto& t : list.tasks()) {
    tasks.push_back({{"task_id", t.task_id()},
                     {"kind", t.kind() == orchestrator::v1::TASK_KIND_STOW ? "stow" : "pick"},
                     {"state", StateName(t.state())},
                     {"items_done", t.items_done()},
                     {"items_total", t.items_total()}});
  }
  std::sort(tasks.begin(), tasks.end(), [](const nlohmann::json& a, const nlohmann::json& b) {
    return a["task_id"].get<std::string>() > b["task_id"].get<std::string>();
  });
  res.set_content(nlohmann::json({{"tasks", tasks}}).dump(), "application/json");
}

std::shared_ptr<TaskFollower> ViewerHttp::FollowerFor(const httplib::Request& req,
                                                      httplib::Response& res) {
  const std::string task_id = req.has_param("task") ? req.get_param_value("task") : "";
  if (!ValidTaskId(task_id)) {
    Error(res, 400, "task: not a task id (letters, digits, '-', '_', '.'; at most 128)");
    return nullptr;
  }
  if (stopping_) {
    Error(res, 503, "the viewer is stopping");
    return nullptr;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto it = followers_.begin(); it != followers_.end(); ++it) {
    if (it->first == task_id) {
      followers_.splice(followers_.begin(), followers_, it);
      return it->second;
    }
  }
  followers_.emplace_front(task_id, std::make_shared<TaskFollower>(orchestrator_, model_, task_id));
  // The least recently asked-for task stops being followed (its open pages keep it alive).
  if (static_cast<int>(followers_.size()) > settings_.max_tasks) followers_.pop_back();
  return followers_.front().second;
}

nlohmann::json ViewerHttp::Status(TaskFollower& follower) {
  const nlohmann::json task_side =
      follower.store().Snapshot().value("orchestrator", nlohmann::json::object());
  const nlohmann::json arm_side = arm_.store().Snapshot().value("robot", nlohmann::json::object());
  std::string message = task_side.value("message", "");
  const std::string robot_message = arm_side.value("message", "");
  if (!robot_message.empty()) message += (message.empty() ? "" : "; ") + robot_message;
  return {{"orchestrator", task_side.value("orchestrator", "unreachable")},
          {"robot", arm_side.value("robot", "unreachable")},
          {"message", message}};
}

nlohmann::json ViewerHttp::View(TaskFollower& follower) {
  const nlohmann::json parts = follower.store().Snapshot();
  const nlohmann::json arm = arm_.store().Snapshot();
  const nlohmann::json task = parts.value("task", nlohmann::json::object());
  return {{"status", Status(follower)},
          {"task", task.value("task", nlohmann::json())},
          {"items", task.value("items", nlohmann::json::array())},
          {"log", task.value("log", nlohmann::json::array())},
          {"arm", arm.value("arm", nlohmann::json())},
          {"scan", parts.value("scan", nlohmann::json())},
          {"detections", parts.value("detections", nlohmann::json::array())},
          {"path", parts.value("path", nlohmann::json())}};
}

void ViewerHttp::Stream(std::shared_ptr<TaskFollower> follower, httplib::Response& res) {
  res.set_header("Cache-Control", "no-cache");
  res.set_header("X-Accel-Buffering", "no");
  struct Reader {
    PartStore::Seen task, arm;
    std::chrono::steady_clock::time_point last_write = std::chrono::steady_clock::now();
  };
  auto reader = std::make_shared<Reader>();
  res.set_chunked_content_provider(
      "text/event-stream", [this, follower, reader](std::size_t, httplib::DataSink& sink) {
        if (stopping_) return false;
        std::string out;
        bool status = false;
        auto add = [&](const std::vector<std::pair<std::string, std::string>>& changes) {
          for (const auto& [name, json] : changes) {
            if (name == "orchestrator" || name == "robot") {
              status = true;
            } else {
              out += SseEvent(name, json);
            }
          }
        };
        add(follower->store().Changes(reader->task, kStreamPoll));
        add(arm_.store().Changes(reader->arm, std::chrono::milliseconds(0)));
        if (status) out += SseEvent("status", Status(*follower).dump());
        const auto now = std::chrono::steady_clock::now();
        if (out.empty() &&
            std::chrono::duration<double>(now - reader->last_write).count() > kKeepAliveS) {
          out = ": keep-alive\n\n";  // a comment line: proxies keep the stream open
        }
        if (out.empty()) return true;
        reader->last_write = now;
        return sink.write(out.data(), out.size());
      });
}

}  // namespace

ViewerSettings ViewerSettings::FromConfig(const runtime::Config& config) {
  ViewerSettings s;
  s.http_listen = config.GetString("http_listen", s.http_listen);
  SplitListen(s.http_listen);
  s.orchestrator_address = config.GetString("orchestrator.address", s.orchestrator_address);
  s.robot_address = config.GetString("robot.address", s.robot_address);
  s.data_dir = config.GetPath("data_dir", apc::DefaultDataDir());
  s.cell_path = config.GetPath("cell", world::DefaultCellConfigPath(s.data_dir));
  s.web_dir = config.GetPath("web_dir", s.data_dir + "/viewer");
  s.three_dir = config.GetPath("three_dir", s.three_dir);
  s.arm_rate_hz = config.GetDouble("arm_rate_hz", s.arm_rate_hz);
  s.max_tasks = static_cast<int>(config.GetInt("max_tasks", s.max_tasks));
  if (!(s.arm_rate_hz > 0.5 && s.arm_rate_hz <= 50.0)) {
    throw std::invalid_argument("setting 'arm_rate_hz': must be in (0.5, 50]");
  }
  if (s.max_tasks < 1 || s.max_tasks > 64) {
    throw std::invalid_argument("setting 'max_tasks': must be in [1, 64]");
  }
  for (const auto& [key, value] :
       {std::pair<const char*, const std::string*>{"orchestrator.address", &s.orchestrator_address},
        {"robot.address", &s.robot_address}}) {
    if (value->empty()) throw std::invalid_argument(std::string("setting '") + key + "': empty");
  }
  return s;
}

runtime::ServiceSet BuildViewerServices(const runtime::Config& config) {
  const ViewerSettings settings = ViewerSettings::FromConfig(config);
  const runtime::ChannelFactory channels = runtime::ChannelFactory::FromConfig(config);
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  auto http =
      std::make_shared<ViewerHttp>(settings, channels.Connect(settings.orchestrator_address, args),
                                   channels.Connect(settings.robot_address, args));
  const int port = http->Start();
  const std::string host = SplitListen(settings.http_listen).first;
  const std::string shown = host == "0.0.0.0" || host.empty() ? "localhost" : host;
  runtime::LogInfo("serving the page",
                   {{"url", "http://" + shown + ":" + std::to_string(port) + "/"}});
  runtime::ServiceSet set;
  set.on_shutdown = [http] { http->Stop(); };
  return set;
}

}  // namespace picking::viewer
