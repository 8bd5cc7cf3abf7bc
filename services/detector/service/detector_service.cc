#include "services/detector/service/detector_service.h"

#include <grpcpp/server_context.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "google/rpc/status.pb.h"
#include "libs/apc/catalogue.h"
#include "libs/errors/errors.h"
#include "libs/proto_convert/proto_convert.h"
#include "libs/runtime/log.h"
#include "libs/runtime/status.h"
#include "services/detector/core/budget_clock.h"
#include "services/detector/core/detect_in_region.h"
#include "services/detector/core/detection.h"
#include "services/detector/core/estimators.h"
#include "services/detector/core/model_library.h"
#include "services/detector/core/preprocess.h"
#include "services/detector/core/verify.h"

namespace picking::detector {
namespace {

namespace pb = ::picking::detector::v1;
namespace pc = ::picking::proto_convert;
using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

pb::Method ToProto(Method method) {
  switch (method) {
    case Method::kPpf:
      return pb::METHOD_PPF;
    case Method::kSift:
      return pb::METHOD_SIFT;
    case Method::kRangeTemplates:
      return pb::METHOD_RANGE_TEMPLATES;
  }
  throw std::logic_error("ToProto: invalid Method");
}

pb::Method ToProto(const std::string& method_name) {
  return ToProto(MethodFromString(method_name));
}

pb::ModelSource ToProto(ModelSourceKind kind) {
  return kind == ModelSourceKind::kScan ? pb::MODEL_SOURCE_SCAN : pb::MODEL_SOURCE_SHAPE;
}

pb::ModelSymmetry ToProto(ModelSymmetry symmetry) {
  switch (symmetry) {
    case ModelSymmetry::kNone:
      return pb::MODEL_SYMMETRY_NONE;
    case ModelSymmetry::kBox:
      return pb::MODEL_SYMMETRY_BOX;
    case ModelSymmetry::kCylinderX:
      return pb::MODEL_SYMMETRY_CYLINDER_X;
    case ModelSymmetry::kCylinderZ:
      return pb::MODEL_SYMMETRY_CYLINDER_Z;
    case ModelSymmetry::kSphere:
      return pb::MODEL_SYMMETRY_SPHERE;
  }
  throw std::logic_error("ToProto: invalid ModelSymmetry");
}

// The symmetry a manifest's note asks for, as the model library uses it: a free-form note is
// no symmetry.
pb::ModelSymmetry SymmetryToProto(const std::string& note) {
  try {
    return ToProto(ModelSymmetryFromString(note));
  } catch (const std::invalid_argument&) {
    return pb::MODEL_SYMMETRY_NONE;
  }
}

// Settings of the service that are not the model library's.
struct ServiceSettings {
  std::uint64_t max_points = 5'000'000;
  // Multiplies every item's time budget: a detector sharing its cores with other work keeps
  // the search a quiet machine would make, at the cost of slower calls.
  double time_budget_scale = 1.0;
  // The clock the items' time budgets are judged by: the steady one, or (budget_clock=frozen,
  // for tests) one standing still, so that every method searches as on a quiet machine.
  BudgetClock budget_clock;
  // budget_clock=thread_cpu: each call's budgets by the CPU time of the thread serving it
  // (BudgetClock::ThreadCpu), made per call.
  bool per_call_thread_cpu = false;
  BudgetClock ForThisCall() const {
    return per_call_thread_cpu ? BudgetClock::ThreadCpu(pthread_self()) : budget_clock;
  }
  PinholeCamera default_camera{640, 480, 525.0, 525.0, 319.5, 239.5};  // Unorganised clouds.
};

// The `budget_clock` setting. Throws std::invalid_argument for an unknown value.
void SetBudgetClock(const std::string& value, ServiceSettings* settings) {
  settings->per_call_thread_cpu = value == "thread_cpu";
  if (value == "steady" || value == "thread_cpu") {
    settings->budget_clock = BudgetClock();
  } else if (value == "frozen") {
    settings->budget_clock = BudgetClock::Frozen();
  } else {
    throw std::invalid_argument(
        "setting 'budget_clock' must be 'thread_cpu', 'steady' or 'frozen', got '" +
        value.substr(0, 40) + "'");
  }
}

// The call deadline on the steady clock (max when the call has none).
Clock::time_point SteadyDeadline(const grpc::ServerContext* ctx) {
  const auto deadline = ctx->deadline();
  if (deadline == std::chrono::system_clock::time_point::max()) return Clock::time_point::max();
  const auto remaining = deadline - std::chrono::system_clock::now();
  if (remaining > std::chrono::hours(24 * 365)) return Clock::time_point::max();
  return Clock::now() + std::chrono::duration_cast<Clock::duration>(remaining);
}

// A cloud received from a client stream, ready for the estimators.
struct ReceivedScene {
  geometry::PointCloud cloud;
  std::uint64_t points_received = 0;
  bool has_sensor_pose = false;
  Eigen::Isometry3d X_BaseSensor = Eigen::Isometry3d::Identity();
};

// Reads the cloud chunks that follow the params. `Request` is DetectRequest or VerifyRequest.
template <class Request>
ReceivedScene ReadCloud(grpc::ServerReader<Request>* reader, const ServiceSettings& settings) {
  pc::CloudAssembler assembler(settings.max_points);
  Request message;
  std::size_t index = 1;
  while (reader->Read(&message)) {
    if (message.has_params()) {
      throw std::invalid_argument("message " + std::to_string(index) +
                                  ": params may only be sent once, as the first message");
    }
    if (!message.has_cloud()) {
      throw std::invalid_argument("message " + std::to_string(index) + ": no payload");
    }
    assembler.Add(message.cloud());
    ++index;
  }
  if (!assembler.started()) throw std::invalid_argument("no point cloud followed the params");
  ReceivedScene scene;
  scene.points_received = assembler.points_received();
  scene.cloud = assembler.Finish();
  scene.has_sensor_pose = assembler.has_sensor_pose();
  if (scene.has_sensor_pose) scene.X_BaseSensor = assembler.sensor_pose();
  CloudLimits limits;
  limits.max_points = settings.max_points;
  ValidateCloud(scene.cloud, limits);   // Empty, NaN-only or inconsistent clouds.
  IntensitiesFromColors(&scene.cloud);  // SIFT works on intensities.
  return scene;
}

pb::MethodAttempt::Outcome ToProto(AttemptOutcome outcome) {
  switch (outcome) {
    case AttemptOutcome::kAccepted:
      return pb::MethodAttempt::OUTCOME_ACCEPTED;
    case AttemptOutcome::kBelowThresholds:
      return pb::MethodAttempt::OUTCOME_BELOW_THRESHOLDS;
    case AttemptOutcome::kNoCandidate:
      return pb::MethodAttempt::OUTCOME_NO_CANDIDATE;
    case AttemptOutcome::kCannotRun:
      return pb::MethodAttempt::OUTCOME_CANNOT_RUN;
    case AttemptOutcome::kFailed:
      return pb::MethodAttempt::OUTCOME_FAILED;
    case AttemptOutcome::kUnavailable:
      return pb::MethodAttempt::OUTCOME_UNAVAILABLE;
    case AttemptOutcome::kNotStarted:
      return pb::MethodAttempt::OUTCOME_NOT_STARTED;
  }
  return pb::MethodAttempt::OUTCOME_UNSPECIFIED;
}

void FillAttempt(const ChainAttempt& attempt, pb::MethodAttempt* out) {
  out->set_method(ToProto(attempt.method));
  out->set_outcome(ToProto(attempt.outcome));
  out->set_reason(attempt.reason);
  out->set_candidates(static_cast<std::uint32_t>(attempt.num_candidates));
  out->set_best_score(attempt.best ? attempt.best->score : 0.0);
  out->set_duration_s(attempt.duration_s);
}

void FillDetection(const Detection& d, double shared_preprocess_s, pb::Detection* out) {
  out->set_item(d.item);
  *out->mutable_x_frame_item() = pc::PoseToProto(d.X_BaseItem);
  out->set_score(d.score);
  out->set_visible_points(static_cast<std::uint32_t>(d.visible_points));
  out->set_occluded_points(static_cast<std::uint32_t>(d.occluded_points));
  out->set_supported_points(static_cast<std::uint32_t>(d.supported_points));
  out->set_conflict_points(static_cast<std::uint32_t>(d.conflict_points));
  out->set_outline_points(static_cast<std::uint32_t>(d.outline_points));
  out->set_outline_continued_points(static_cast<std::uint32_t>(d.outline_continued));
  out->set_method(ToProto(d.method));
  out->set_fitness(d.fitness);
  out->set_inlier_rmse_m(d.inlier_rmse_m);
  out->set_has_appearance(std::isfinite(d.appearance));
  if (out->has_appearance()) out->set_appearance(d.appearance);
  auto* t = out->mutable_timings();
  t->set_preprocess_s(shared_preprocess_s + d.timings.preprocess_s);
  t->set_match_s(d.timings.estimate_s);
  t->set_refine_s(d.timings.refine_s);
  t->set_verify_s(d.timings.verify_s);
  t->set_total_s(shared_preprocess_s + d.timings.total_s);
}

class DetectorServiceImpl final : public pb::DetectorService::Service {
 public:
  DetectorServiceImpl(std::shared_ptr<const ModelLibrary> library, ServiceSettings settings)
      : library_(std::move(library)), settings_(settings) {}

  grpc::Status Detect(grpc::ServerContext* ctx, grpc::ServerReader<pb::DetectRequest>* reader,
                      pb::DetectResponse* response) override {
    return runtime::Guard([&] {
      const auto start = Clock::now();
      pb::DetectRequest first;
      if (!reader->Read(&first) || !first.has_params()) {
        return runtime::InvalidArgument(
            "the first message of a Detect stream must be `params` (then the cloud chunks)");
      }
      const pb::DetectParams params = first.params();
      ValidateParams(params);
      // Stacked views' sensor poses, checked before the cloud is read.
      std::vector<Eigen::Isometry3d> view_poses;
      for (int k = 0; k < params.x_frame_sensor_size(); ++k) {
        view_poses.push_back(pc::PoseFromProto(params.x_frame_sensor(k),
                                               "params.X_frame_sensor[" + std::to_string(k) + "]"));
      }
      ReceivedScene received = ReadCloud(reader, settings_);
      response->set_points_received(received.points_received);
      // An item's time budget covers its share of the work on the received cloud: the first
      // item's includes the shared pre-processing.
      const BudgetClock budget_clock = settings_.ForThisCall();
      Clock::time_point budget_start = budget_clock.Now();

      SceneOptions scene_options;
      if (params.has_region()) {
        scene_options.region = RegionBox(params.region());
        scene_options.wall_margin_m = params.region().wall_margin_m();
      }
      scene_options.view_poses = std::move(view_poses);
      scene_options.fallback_camera = settings_.default_camera;
      if (params.has_camera()) {
        scene_options.camera = pc::CameraFromProto(params.camera(), "params.camera");
      }
      PreparedScene scene;
      try {
        scene = PrepareScene(std::move(received.cloud), received.X_BaseSensor, scene_options);
      } catch (const ViewPosesError& e) {
        throw std::invalid_argument(std::string("params.X_frame_sensor: ") + e.what());
      } catch (const EmptyRegionError& e) {
        throw std::invalid_argument(std::string("params.region: ") + e.what());
      }
      response->set_points_after_preprocessing(scene.finite_points);
      const std::shared_ptr<SceneContext> context = MakeSceneContext(scene);
      context->set_deadline(SteadyDeadline(ctx));
      const double shared_preprocess_s = SecondsSince(start);

      for (const pb::ItemQuery& query : params.queries()) {
        context->CheckDeadline();
        pb::ItemResult* result = response->add_results();
        result->set_item(query.item());
        try {
          DetectOne(query, scene, context, shared_preprocess_s, budget_clock, budget_start, result);
        } catch (const TimeoutError&) {
          throw;
        } catch (...) {
          const grpc::Status status = runtime::StatusFromCurrentException();
          result->mutable_status()->set_code(static_cast<int>(status.error_code()));
          result->mutable_status()->set_message(status.error_message());
        }
        if (ctx->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "cancelled");
        budget_start = budget_clock.Now();
      }
      context->CheckDeadline();
      return grpc::Status::OK;
    });
  }

  grpc::Status Verify(grpc::ServerContext*, grpc::ServerReader<pb::VerifyRequest>* reader,
                      pb::VerifyResponse* response) override {
    return runtime::Guard([&] {
      pb::VerifyRequest first;
      if (!reader->Read(&first) || !first.has_params()) {
        return runtime::InvalidArgument(
            "the first message of a Verify stream must be `params` (then the cloud chunks)");
      }
      const pb::VerifyParams params = first.params();
      if (params.item().empty()) throw std::invalid_argument("params.item is empty");
      if (!params.has_x_frame_item()) throw std::invalid_argument("params.X_frame_item is unset");
      const Eigen::Isometry3d X_BaseItem =
          pc::PoseFromProto(params.x_frame_item(), "params.X_frame_item");
      std::optional<Eigen::Isometry3d> X_BaseSensor;
      if (params.has_x_frame_sensor()) {
        X_BaseSensor = pc::PoseFromProto(params.x_frame_sensor(), "params.X_frame_sensor");
      }
      const auto model = library_->Get(params.item());  // NOT_FOUND for unknown items.
      const ReceivedScene received = ReadCloud(reader, settings_);
      if (!X_BaseSensor) X_BaseSensor = received.X_BaseSensor;
      const PinholeCamera camera =
          CameraFor(received.cloud, *X_BaseSensor).value_or(settings_.default_camera);
      const VerificationScene scene(received.cloud, *X_BaseSensor, camera);
      // As Detect verifies its candidates: the symmetric turn whose print fits is reported and
      // a contradicting print lowers the score.
      VerifyOptions options = RefineVerifyOptions().verify;
      options.symmetries = model->object->symmetries();
      const VerifyResult r =
          detector::Verify(scene, model->object->icp_cloud(), X_BaseItem, options);
      response->set_score(r.score);
      response->set_has_appearance(r.appearance.defined);
      if (r.appearance.defined) response->set_appearance(r.appearance.correlation);
      *response->mutable_x_frame_item_appearance() = pc::PoseToProto(r.X_BaseItem_appearance);
      response->set_visible_model_points(
          static_cast<std::uint32_t>(r.num_visible - r.num_occluded));
      response->set_supported_model_points(static_cast<std::uint32_t>(r.num_supported));
      response->set_conflicting_model_points(static_cast<std::uint32_t>(r.num_conflicts));
      response->set_outline_points(static_cast<std::uint32_t>(r.num_outline));
      response->set_outline_continued_points(static_cast<std::uint32_t>(r.num_outline_continued));
      response->set_outline_factor(r.outline_factor);
      return grpc::Status::OK;
    });
  }

  grpc::Status ListModels(grpc::ServerContext*, const pb::ListModelsRequest*,
                          pb::ListModelsResponse* response) override {
    return runtime::Guard([&] {
      // Models are built on first use: those not built yet report diameter_m and
      // model_points 0.
      for (const ModelSpec& spec : library_->manifest().models()) {
        pb::ModelInfo* info = response->add_models();
        info->set_item(spec.item);
        info->set_source(ToProto(spec.kind));
        info->set_symmetry(SymmetryToProto(spec.symmetry));
        const ObjectConfig config = library_->ConfigFor(spec.item);
        info->set_preferred_method(ToProto(config.preferred));
        for (Method m : config.fallbacks) info->add_fallbacks(ToProto(m));
        if (const auto model = library_->GetIfLoaded(spec.item)) {
          info->set_diameter_m(model->object->diameter_m());
          info->set_model_points(static_cast<std::uint32_t>(model->object->fine_cloud().size()));
        }
      }
      response->set_cache_format_version(ObjectModel::kCacheVersion);
      return grpc::Status::OK;
    });
  }

 private:
  static void ValidateParams(const pb::DetectParams& params) {
    if (params.queries().empty()) throw std::invalid_argument("params.queries is empty");
    for (int i = 0; i < params.queries_size(); ++i) {
      const pb::ItemQuery& q = params.queries(i);
      const std::string field = "params.queries[" + std::to_string(i) + "]";
      if (q.item().empty()) throw std::invalid_argument(field + ".item is empty");
      if (!pb::Method_IsValid(q.method())) {
        throw std::invalid_argument(field + ".method: unknown value " + std::to_string(q.method()));
      }
      if (!(q.min_score() >= 0.0 && q.min_score() <= 1.0)) {
        throw std::invalid_argument(field + ".min_score must be in [0, 1]");
      }
    }
  }

  static OrientedBox RegionBox(const pb::Region& region) {
    OrientedBox box;
    box.X_BaseBox = pc::PoseFromProto(region.x_frame_region(), "params.region.X_frame_region");
    box.size_m = pc::VectorFromProto(region.size_m(), "params.region.size_m");
    try {
      box.Validate();
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument(std::string("params.region.size_m: ") + e.what());
    }
    if (!(region.wall_margin_m() >= 0.0) || 2.0 * region.wall_margin_m() >= box.size_m.minCoeff()) {
      throw std::invalid_argument(
          "params.region.wall_margin_m must be >= 0 and less than half the smallest box side");
    }
    return box;
  }

  std::optional<PinholeCamera> CameraFor(const geometry::PointCloud& scene,
                                         const Eigen::Isometry3d& X_BaseSensor) const {
    if (auto fitted = FitOrganizedIntrinsics(scene, X_BaseSensor)) return fitted;
    return settings_.default_camera;
  }

  void DetectOne(const pb::ItemQuery& query, const PreparedScene& scene,
                 const std::shared_ptr<SceneContext>& context, double shared_preprocess_s,
                 const BudgetClock& budget_clock, Clock::time_point budget_start,
                 pb::ItemResult* result) const {
    ItemQuery item_query;
    item_query.item = query.item();
    switch (query.method()) {
      case pb::METHOD_PPF:
        item_query.method = Method::kPpf;
        break;
      case pb::METHOD_SIFT:
        item_query.method = Method::kSift;
        break;
      case pb::METHOD_RANGE_TEMPLATES:
        item_query.method = Method::kRangeTemplates;
        break;
      default:
        break;
    }
    item_query.min_score = query.min_score();
    item_query.max_results = query.max_results() == 0 ? 1 : query.max_results();
    item_query.budget_scale = settings_.time_budget_scale;
    item_query.budget_clock = budget_clock;
    const ItemDetections found = DetectItem(library_, scene, context, item_query, budget_start);
    for (const ChainAttempt& attempt : found.chain.attempts) {
      const bool ran = attempt.outcome != AttemptOutcome::kUnavailable &&
                       attempt.outcome != AttemptOutcome::kNotStarted;
      if (ran) result->add_methods_tried(ToProto(attempt.method));
      FillAttempt(attempt, result->add_attempts());
      if (!attempt.error.empty()) {
        runtime::LogWarning("detection method failed", {{"item", query.item()},
                                                        {"method", ToString(attempt.method)},
                                                        {"error", attempt.error}});
      }
    }
    result->mutable_status()->set_code(0);
    for (const Detection& d : found.poses) {
      FillDetection(d, shared_preprocess_s, result->add_detections());
    }
  }

  std::shared_ptr<const ModelLibrary> library_;
  ServiceSettings settings_;
};

}  // namespace

runtime::ServiceSet BuildDetectorServices(const runtime::Config& config) {
  const std::string data_dir = config.GetString("data_dir", apc::DefaultDataDir());
  const std::string manifest_path = config.GetString("models", data_dir + "/detector/models.json");
  ModelLibraryOptions options;
  options.cache_dir = config.GetString("cache_dir", DefaultDetectorCacheDir());
  options.catalogue_path = config.GetString("catalogue", data_dir + "/apc2016/items/item_data.csv");
  const bool preload = config.GetBool("preload", false);

  ServiceSettings settings;
  const long long max_points = config.GetInt("max_points", 5'000'000);
  if (max_points < 1 || static_cast<std::uint64_t>(max_points) > pc::kMaxStreamPoints) {
    throw std::invalid_argument("setting 'max_points' must be in [1, " +
                                std::to_string(pc::kMaxStreamPoints) + "]");
  }
  settings.max_points = static_cast<std::uint64_t>(max_points);
  settings.time_budget_scale = config.GetDouble("time_budget_scale", 1.0);
  if (!(settings.time_budget_scale > 0.0) || !std::isfinite(settings.time_budget_scale)) {
    throw std::invalid_argument("setting 'time_budget_scale' must be positive and finite");
  }
  SetBudgetClock(config.GetString("budget_clock", "thread_cpu"), &settings);
  try {
    settings.default_camera =
        PinholeCamera(static_cast<int>(config.GetInt("camera.width", 640)),
                      static_cast<int>(config.GetInt("camera.height", 480)),
                      config.GetDouble("camera.fx", 525.0), config.GetDouble("camera.fy", 525.0),
                      config.GetDouble("camera.cx", 319.5), config.GetDouble("camera.cy", 239.5));
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("settings 'camera.*': ") + e.what());
  }

  auto library = std::make_shared<const ModelLibrary>(
      ModelManifest::LoadFile(manifest_path, data_dir), std::move(options));
  if (preload) {
    const auto start = Clock::now();
    library->LoadAll();
    runtime::LogInfo("models loaded",
                     {{"count", std::to_string(library->manifest().models().size())},
                      {"seconds", std::to_string(SecondsSince(start))}});
  }
  runtime::ServiceSet set;
  set.Add(std::make_shared<DetectorServiceImpl>(std::move(library), settings),
          pb::DetectorService::service_full_name());
  return set;
}

}  // namespace picking::detector
