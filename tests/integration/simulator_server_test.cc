// Integration test of the picking-simulator server binary through its generated client.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>
#include <signal.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iostream>
#include <limits>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

namespace sim = ::picking::simulator::v1;
namespace common = ::picking::common::v1;

const char kBinary[] = "picking-simulator";
const std::vector<double> kHome = {0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0};

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

std::string TaskJson(const std::string& name) {
  return ReadText(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/" + name + ".json");
}

// A task JSON with `bin_a` (a JSON array text) in bin_A and every other bin empty.
std::string TaskWithBinA(const std::string& bin_a) {
  std::string json = "{\"bin_contents\": {\"bin_A\": " + bin_a;
  for (char b = 'B'; b <= 'L'; ++b) json += std::string(", \"bin_") + b + "\": []";
  return json + "}, \"tote_contents\": []}";
}

TEST(SimulatorServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary), "picking.simulator.v1.SimulatorService",
                                "picking/simulator/v1/simulator.proto");
}

TEST(SimulatorServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

TEST(SimulatorServerTest, RefusesAnUnreadableLayoutSetting) {
  const ProgramResult r =
      RunProgram(ServerBinary(kBinary), {"--listen=127.0.0.1:0", "--layout=/nonexistent.json"});
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("layout"), std::string::npos) << r.output;
}

// The bundled cell description with its gripper section replaced by `gripper` (YAML text,
// may be empty) and its mesh paths made absolute, written to a file of the test's own.
std::string CellWithGripper(const std::string& name, const std::string& gripper) {
  std::string yaml = ReadText(std::string(PICKING_DATA_DIR) + "/cell/default_cell.yaml");
  const std::string mesh_dir = std::string(PICKING_DATA_DIR) + "/apc2016/";
  for (std::size_t pos; (pos = yaml.find("../apc2016/")) != std::string::npos;) {
    yaml.replace(pos, std::strlen("../apc2016/"), mesh_dir);
  }
  yaml = yaml.substr(0, yaml.find("\ngripper:")) + "\n" + gripper;
  const std::string path = ::testing::TempDir() + "/simulator_test_" + name + ".yaml";
  std::ofstream(path) << yaml;
  return path;
}

TEST(SimulatorServerTest, TakesTheToolCentrePointFromTheCellDescription) {
  ServerProcess server(ServerBinary(kBinary),
                       {"--cell=" + CellWithGripper("short_tube",
                                                    "gripper:\n"
                                                    "  X_ToolTcp: {position: [0, 0, 0.2], "
                                                    "orientation: [1, 0, 0, 0]}\n"
                                                    "  tube_radius_m: 0.02\n"
                                                    "  cup_length_m: 0.02\n")});
  auto stub = sim::SimulatorService::NewStub(server.Channel());
  grpc::ClientContext ctx;
  sim::SetArmJointsRequest req;
  for (double v : kHome) req.mutable_joints()->add_positions_rad(v);
  sim::SetArmJointsResponse placed;
  ASSERT_TRUE(stub->SetArmJoints(&ctx, req, &placed).ok());
  const auto& tool = placed.x_base_tool().position();
  const auto& tcp = placed.x_base_tcp().position();
  EXPECT_NEAR(std::hypot(tcp.x() - tool.x(), tcp.y() - tool.y(), tcp.z() - tool.z()), 0.2, 1e-9);
  EXPECT_EQ(server.Stop(), 0);
}

TEST(SimulatorServerTest, RefusesACellDescriptionWithoutAGripper) {
  const std::string cell = CellWithGripper("no_gripper", "");
  const ProgramResult r =
      RunProgram(ServerBinary(kBinary), {"--listen=127.0.0.1:0", "--cell=" + cell});
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("gripper"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find(cell), std::string::npos) << r.output;
}

TEST(SimulatorServerTest, LoadsTheLayoutSettingAtStart) {
  ServerProcess server(ServerBinary(kBinary), {"--layout=" + std::string(PICKING_DATA_DIR) +
                                                   "/apc2016/tasks/pick_layout_2.json",
                                               "--seed=5"});
  auto stub = sim::SimulatorService::NewStub(server.Channel());
  grpc::ClientContext ctx;
  sim::GetGroundTruthResponse truth;
  ASSERT_TRUE(stub->GetGroundTruth(&ctx, sim::GetGroundTruthRequest(), &truth).ok());
  EXPECT_GT(truth.items_size(), 20);
  EXPECT_EQ(server.Stop(), 0);
}

// layout_mode=settled: the layout setting's items dropped and settled by physics, every one
// in its bin or the tote; an unknown mode stops the server with the setting named.
TEST(SimulatorServerTest, SettlesTheLayoutByPhysicsWhenAsked) {
  ServerProcess server(ServerBinary(kBinary), {"--layout=" + std::string(PICKING_DATA_DIR) +
                                                   "/apc2016/tasks/pick_layout_1.json",
                                               "--seed=7", "--layout_mode=settled"});
  auto stub = sim::SimulatorService::NewStub(server.Channel());
  grpc::ClientContext ctx;
  sim::GetGroundTruthResponse truth;
  ASSERT_TRUE(stub->GetGroundTruth(&ctx, sim::GetGroundTruthRequest(), &truth).ok());
  EXPECT_EQ(truth.items_size(), 46);
  EXPECT_EQ(server.Stop(), 0);
  const ProgramResult r =
      RunProgram(ServerBinary(kBinary), {"--listen=127.0.0.1:0", "--layout_mode=stacked"});
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("layout_mode"), std::string::npos) << r.output;
}

// One server for the RPC tests; each test loads the layout it needs.
class SimulatorRpcTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { server_ = new ServerProcess(ServerBinary(kBinary)); }
  static void TearDownTestSuite() {
    EXPECT_EQ(server_->Stop(), 0);
    delete server_;
  }
  SimulatorRpcTest() : stub_(sim::SimulatorService::NewStub(server_->Channel())) {}

  grpc::Status Load(const std::string& json, std::uint64_t seed,
                    sim::LoadLayoutResponse* out = nullptr) {
    grpc::ClientContext ctx;
    sim::LoadLayoutRequest req;
    req.set_task_json(json);
    req.set_seed(seed);
    sim::LoadLayoutResponse response;
    return stub_->LoadLayout(&ctx, req, out ? out : &response);
  }
  sim::GetGroundTruthResponse Truth() {
    grpc::ClientContext ctx;
    sim::GetGroundTruthResponse truth;
    EXPECT_TRUE(stub_->GetGroundTruth(&ctx, sim::GetGroundTruthRequest(), &truth).ok());
    return truth;
  }
  grpc::Status SetJoints(const std::vector<double>& q, sim::SetArmJointsResponse* out) {
    grpc::ClientContext ctx;
    sim::SetArmJointsRequest req;
    for (double v : q) req.mutable_joints()->add_positions_rad(v);
    return stub_->SetArmJoints(&ctx, req, out);
  }
  sim::GetCellResponse Cell() {
    grpc::ClientContext ctx;
    sim::GetCellResponse cell;
    EXPECT_TRUE(stub_->GetCell(&ctx, sim::GetCellRequest(), &cell).ok());
    return cell;
  }

  static ServerProcess* server_;
  std::unique_ptr<sim::SimulatorService::Stub> stub_;
};
ServerProcess* SimulatorRpcTest::server_ = nullptr;

TEST_F(SimulatorRpcTest, LoadLayoutPlacesEveryItemOfTheTaskReproducibly) {
  sim::LoadLayoutResponse a, b, c;
  ASSERT_TRUE(Load(TaskJson("pick_layout_1"), 11, &a).ok());
  // pick_layout_1 holds 46 items in the bins and none in the tote.
  ASSERT_EQ(a.items_size(), 46);
  std::multiset<std::string> names;
  for (const auto& s : a.items()) {
    EXPECT_GE(s.container(), common::CONTAINER_BIN_A);
    EXPECT_LE(s.container(), common::CONTAINER_BIN_L);
    names.insert(s.item().name());
  }
  EXPECT_EQ(names.count("staples_index_cards"), 2u);
  EXPECT_EQ(names.count("kleenex_tissue_box"), 1u);
  // Instances number the copies of one item 0, 1, ...
  std::set<std::uint32_t> instances;
  for (const auto& s : a.items()) {
    if (s.item().name() == "staples_index_cards") instances.insert(s.item().instance());
  }
  EXPECT_EQ(instances, (std::set<std::uint32_t>{0, 1}));

  ASSERT_TRUE(Load(TaskJson("pick_layout_1"), 11, &b).ok());
  EXPECT_EQ(a.SerializeAsString(), b.SerializeAsString()) << "same seed, same layout";
  ASSERT_TRUE(Load(TaskJson("pick_layout_1"), 12, &c).ok());
  EXPECT_NE(a.SerializeAsString(), c.SerializeAsString()) << "another seed, another layout";
  // Ground truth agrees with the answer and has no events after a fresh load.
  const auto truth = Truth();
  ASSERT_EQ(truth.items_size(), c.items_size());
  EXPECT_EQ(truth.events_size(), 0);
}

TEST_F(SimulatorRpcTest, CellHasTwelveBinsOpeningTowardTheRobot) {
  const auto cell = Cell();
  ASSERT_EQ(cell.bins_size(), 12);
  for (int i = 0; i < 12; ++i) {
    const auto& bin = cell.bins(i);
    EXPECT_EQ(bin.bin(), common::CONTAINER_BIN_A + i);
    // The APC 2016 pod: bins 0.25-0.30 m wide, 0.22-0.27 m tall, about 0.43 m deep.
    EXPECT_GT(bin.size_m().x(), 0.35);
    EXPECT_LT(bin.size_m().x(), 0.5);
    EXPECT_GT(bin.size_m().y(), 0.2);
    EXPECT_LT(bin.size_m().y(), 0.33);
    EXPECT_GT(bin.size_m().z(), 0.18);
    EXPECT_LT(bin.size_m().z(), 0.3);
    // In front of the robot: the opening at about 0.81 m, centres between it and the pod's back.
    EXPECT_GT(bin.x_base_bin().position().x(), 0.85);
    EXPECT_LT(bin.x_base_bin().position().x(), 1.25);
  }
  // bin_A is the top left seen from the robot (+y), bin_L the bottom right.
  EXPECT_GT(cell.bins(0).x_base_bin().position().y(), 0.2);
  EXPECT_LT(cell.bins(11).x_base_bin().position().y(), -0.2);
  EXPECT_GT(cell.bins(0).x_base_bin().position().z(), cell.bins(11).x_base_bin().position().z());
  EXPECT_GT(cell.tote_inner_size_m().x(), 0.3);
  EXPECT_GT(cell.tote_inner_size_m().z(), 0.1);
  EXPECT_LT(cell.x_base_tote().position().y(), 0.0);  // to the robot's right
  EXPECT_GT(cell.x_base_table().position().y(), 0.0);
}

TEST_F(SimulatorRpcTest, ArmPlacementReportsCollisionsWithTheShelfOnce) {
  ASSERT_TRUE(Load(TaskJson("pick_layout_1"), 3).ok());
  sim::SetArmJointsResponse placed;
  ASSERT_TRUE(SetJoints(kHome, &placed).ok());
  EXPECT_FALSE(placed.in_collision()) << placed.collision_detail();
  auto truth = Truth();
  ASSERT_EQ(truth.arm_joints().positions_rad_size(), 6);
  for (int i = 0; i < 6; ++i) EXPECT_DOUBLE_EQ(truth.arm_joints().positions_rad(i), kHome[i]);
  EXPECT_EQ(truth.x_base_tcp().SerializeAsString(), placed.x_base_tcp().SerializeAsString());
  // The flange, whose z axis the cup is on (GetGroundTruth derives it from the cup).
  const auto& flange = placed.x_base_tool().position();
  EXPECT_NEAR(truth.x_base_tool().position().x(), flange.x(), 1e-9);
  EXPECT_NEAR(truth.x_base_tool().position().y(), flange.y(), 1e-9);
  EXPECT_NEAR(truth.x_base_tool().position().z(), flange.z(), 1e-9);

  // Turned toward the shelf and stretched out low: the arm is in the pod's solid base.
  const std::vector<double> into_shelf = {M_PI, 0.0, 0.0, 0.0, 0.0, 0.0};
  ASSERT_TRUE(SetJoints(into_shelf, &placed).ok());
  EXPECT_TRUE(placed.in_collision());
  EXPECT_NE(placed.collision_detail().find("shelf"), std::string::npos)
      << placed.collision_detail();
  // The flange at (1.1843, 0.2561, 0.0116) (the DH chain at zero turned by pi about z), the
  // cup 0.35 m from it (the bundled cell's gripper).
  const auto& tool = placed.x_base_tool().position();
  EXPECT_NEAR(tool.x(), 1.1843, 1e-4);
  EXPECT_NEAR(tool.y(), 0.2561, 1e-4);
  EXPECT_NEAR(tool.z(), 0.0116, 1e-4);
  const auto& cup = placed.x_base_tcp().position();
  EXPECT_NEAR(std::hypot(cup.x() - 1.1843, cup.y() - 0.2561, cup.z() - 0.0116), 0.35, 1e-3);
  ASSERT_TRUE(SetJoints(into_shelf, &placed).ok());  // still in collision: no new event
  ASSERT_TRUE(SetJoints(kHome, &placed).ok());
  EXPECT_FALSE(placed.in_collision());
  truth = Truth();
  int collisions = 0;
  for (const auto& e : truth.events()) {
    if (e.kind() == sim::EVENT_KIND_COLLISION) {
      ++collisions;
      EXPECT_NE(e.detail().find("shelf"), std::string::npos);
    }
  }
  EXPECT_EQ(collisions, 1);
}

TEST_F(SimulatorRpcTest, ProbeFindsTheShelfAndItemsAlongTheToolAxis) {
  ASSERT_TRUE(Load(TaskWithBinA("[\"kleenex_tissue_box\"]"), 2).ok());
  const auto cell = Cell();
  const auto truth = Truth();
  ASSERT_EQ(truth.items_size(), 1);
  const auto& box = truth.items(0).x_base_item().position();
  // Flange 0.5 m in front of the box centre, its z axis (the cup's) along +x of base:
  // a rotation of +90 deg about y.
  sim::ProbeContactRequest req;
  auto* pose = req.mutable_x_base_tool();
  pose->mutable_position()->set_x(box.x() - 0.35 - 0.5);
  pose->mutable_position()->set_y(box.y());
  pose->mutable_position()->set_z(box.z());
  pose->mutable_orientation()->set_w(std::sqrt(0.5));
  pose->mutable_orientation()->set_y(std::sqrt(0.5));
  req.mutable_direction_tcp()->set_z(1.0);
  req.set_max_distance_m(1.0);
  sim::ProbeContactResponse probe;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(stub_->ProbeContact(&ctx, req, &probe).ok());
  }
  EXPECT_TRUE(probe.contact());
  EXPECT_EQ(probe.surface(), sim::CONTACT_SURFACE_ITEM);
  EXPECT_EQ(probe.item().name(), "kleenex_tissue_box");
  EXPECT_GT(probe.distance_m(), 0.3);  // the box's front face, less than its half length away
  EXPECT_LT(probe.distance_m(), 0.5);
  EXPECT_GT(probe.stiffness_n_per_m(), 0.0);

  // Straight down into the empty bin_B: its floor.
  const auto& bin = cell.bins(1);
  pose->mutable_position()->set_x(bin.x_base_bin().position().x());
  pose->mutable_position()->set_y(bin.x_base_bin().position().y());
  pose->mutable_position()->set_z(bin.x_base_bin().position().z() + 0.45);
  pose->mutable_orientation()->set_w(0.0);
  pose->mutable_orientation()->set_y(0.0);
  pose->mutable_orientation()->set_x(1.0);  // z of the tool points down
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(stub_->ProbeContact(&ctx, req, &probe).ok());
  }
  EXPECT_TRUE(probe.contact());
  EXPECT_EQ(probe.surface(), sim::CONTACT_SURFACE_SHELF);
  EXPECT_TRUE(probe.item().name().empty());
  // From the cup 0.1 m above the bin centre to the floor half a bin height below.
  EXPECT_NEAR(probe.distance_m(), 0.1 + 0.5 * bin.size_m().z(), 0.02);

  // Short of everything: no contact.
  req.set_max_distance_m(0.05);
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(stub_->ProbeContact(&ctx, req, &probe).ok());
  }
  EXPECT_FALSE(probe.contact());
  EXPECT_EQ(probe.surface(), sim::CONTACT_SURFACE_UNSPECIFIED);
}

TEST_F(SimulatorRpcTest, SuctionInFreeAirDoesNotSeal) {
  ASSERT_TRUE(Load(TaskJson("pick_layout_1"), 3).ok());
  sim::SetArmJointsResponse placed;
  ASSERT_TRUE(SetJoints(kHome, &placed).ok());
  sim::SetSuctionRequest on;
  on.set_on(true);
  sim::SetSuctionResponse r;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(stub_->SetSuction(&ctx, on, &r).ok());
  }
  EXPECT_FALSE(r.sealed());
  EXPECT_TRUE(r.attached_item().name().empty());
  EXPECT_GT(r.vacuum_kpa(), 0.0);
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(stub_->SetSuction(&ctx, sim::SetSuctionRequest(), &r).ok());  // off
  }
  EXPECT_FALSE(r.has_released());
  EXPECT_EQ(r.vacuum_kpa(), 0.0);
  EXPECT_TRUE(Truth().attached_item().name().empty());
}

// A camera and a projector 0.6 m above the base, 0.6 m in front of the bins, looking along +x.
sim::RenderPatternsRequest ShelfView() {
  sim::RenderPatternsRequest req;
  auto model = [](picking::common::v1::CameraIntrinsics* m, int w, int h, double f) {
    m->set_width(w);
    m->set_height(h);
    m->set_fx(f);
    m->set_fy(f);
    m->set_cx(0.5 * (w - 1));
    m->set_cy(0.5 * (h - 1));
  };
  model(req.mutable_camera(), 160, 120, 150.0);
  model(req.mutable_projector(), 128, 96, 110.0);
  // Camera axes in base: x = -y_base, y = -z_base, z = +x_base: quaternion (0.5, -0.5, 0.5, -0.5).
  auto pose = [](common::Pose* p, double y) {
    p->mutable_position()->set_x(0.2);
    p->mutable_position()->set_y(y);
    p->mutable_position()->set_z(0.6);
    p->mutable_orientation()->set_w(0.5);
    p->mutable_orientation()->set_x(-0.5);
    p->mutable_orientation()->set_y(0.5);
    p->mutable_orientation()->set_z(-0.5);
  };
  pose(req.mutable_x_base_camera(), 0.0);
  pose(req.mutable_x_base_projector(), 0.1);
  req.mutable_options()->set_ambient(0.05);
  return req;
}

struct Rendered {
  grpc::Status status;
  std::vector<common::ImageHeader> headers;
  std::vector<std::string> pixels;
};

Rendered Render(sim::SimulatorService::Stub* stub, const sim::RenderPatternsRequest& req) {
  Rendered out;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  auto reader = stub->RenderPatterns(&ctx, req);
  sim::RenderPatternsResponse response;
  while (reader->Read(&response)) {
    const common::ImageChunk& chunk = response.chunk();
    if (chunk.has_header()) {
      out.headers.push_back(chunk.header());
      out.pixels.emplace_back();
    }
    if (out.pixels.empty()) continue;
    EXPECT_EQ(chunk.row_offset() * out.headers.back().width(), out.pixels.back().size());
    out.pixels.back() += chunk.data();
  }
  out.status = reader->Finish();
  return out;
}

double Mean(const std::string& pixels) {
  double sum = 0.0;
  for (unsigned char c : pixels) sum += c;
  return pixels.empty() ? 0.0 : sum / pixels.size();
}

TEST_F(SimulatorRpcTest, RenderPatternsShowsWhereTheProjectorLightsTheScene) {
  ASSERT_TRUE(Load(TaskJson("pick_layout_1"), 3).ok());
  auto req = ShelfView();
  req.add_patterns()->set_solid_level(1.0);
  req.add_patterns()->set_solid_level(0.0);
  auto* stripes = req.add_patterns()->mutable_gray_code();
  stripes->set_bit(0);
  req.add_patterns()->set_mono8(std::string(128 * 96, '\xff'));
  const Rendered r = Render(stub_.get(), req);
  ASSERT_TRUE(r.status.ok()) << r.status.error_message();
  ASSERT_EQ(r.headers.size(), 4u);
  for (std::size_t i = 0; i < r.headers.size(); ++i) {
    EXPECT_EQ(r.headers[i].width(), 160u);
    EXPECT_EQ(r.headers[i].height(), 120u);
    EXPECT_EQ(r.headers[i].index(), i);
    EXPECT_EQ(r.headers[i].format(), common::PIXEL_FORMAT_MONO8);
    ASSERT_EQ(r.pixels[i].size(), 160u * 120u);
  }
  EXPECT_EQ(r.headers[2].name(), "pattern/col/0");
  const double white = Mean(r.pixels[0]), black = Mean(r.pixels[1]), half = Mean(r.pixels[2]);
  EXPECT_GT(white, black + 30.0) << "white " << white << " black " << black;
  // The most significant column bit lights about half of the projector.
  EXPECT_GT(half, black + 0.2 * (white - black));
  EXPECT_LT(half, white - 0.2 * (white - black));
  EXPECT_EQ(r.pixels[3], r.pixels[0]) << "mono8 white equals the solid white frame";
}

TEST_F(SimulatorRpcTest, RefusedRequestsNameTheProblemAndChangeNothing) {
  ASSERT_TRUE(Load(TaskJson("pick_layout_1"), 3).ok());
  sim::SetArmJointsResponse placed;
  ASSERT_TRUE(SetJoints(kHome, &placed).ok());
  const std::string before = Truth().SerializeAsString();

  grpc::Status s = Load(TaskWithBinA("[\"no_such_item\"]"), 1);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_NE(s.error_message().find("no_such_item"), std::string::npos) << s.error_message();

  s = Load("{\"bin_contents\": {\"bin_A\": [}", 1);  // malformed JSON
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("line"), std::string::npos) << s.error_message();

  s = Load("{\"bin_contents\": {\"bin_A\": []}, \"tote_contents\": []}", 1);  // bins missing
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("bin_contents"), std::string::npos) << s.error_message();

  std::string many = "[";
  for (int i = 0; i < 12; ++i) many += std::string(i ? ", " : "") + "\"kleenex_paper_towels\"";
  s = Load(TaskWithBinA(many + "]"), 1);  // twelve paper towel rolls in one bin
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(s.error_message().find("bin_A"), std::string::npos) << s.error_message();

  s = Load(TaskJson("pick_layout_1"), std::uint64_t(1) << 40);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("seed"), std::string::npos) << s.error_message();

  const double nan = std::numeric_limits<double>::quiet_NaN();
  s = SetJoints({0, nan, 0, 0, 0, 0}, &placed);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  s = SetJoints({0, 0, 0, 0, 0}, &placed);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  s = SetJoints({0, -1.5, 4.0, 0, 0, 0}, &placed);  // elbow beyond +-pi
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("elbow"), std::string::npos) << s.error_message();

  sim::ProbeContactRequest probe;
  probe.mutable_direction_tcp()->set_z(2.0);  // not a unit vector
  probe.set_max_distance_m(0.1);
  sim::ProbeContactResponse contact;
  {
    grpc::ClientContext ctx;
    s = stub_->ProbeContact(&ctx, probe, &contact);
  }
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("direction_tcp"), std::string::npos);
  probe.mutable_direction_tcp()->set_z(1.0);
  probe.set_max_distance_m(-1.0);
  {
    grpc::ClientContext ctx;
    s = stub_->ProbeContact(&ctx, probe, &contact);
  }
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);

  auto render = ShelfView();
  render.add_patterns()->set_mono8("too short");
  Rendered r = Render(stub_.get(), render);
  EXPECT_EQ(r.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(r.status.error_message().find("patterns[0].mono8"), std::string::npos);
  EXPECT_TRUE(r.headers.empty());
  render = ShelfView();
  render.mutable_camera()->set_width(0);
  render.add_patterns()->set_solid_level(1.0);
  r = Render(stub_.get(), render);
  EXPECT_EQ(r.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(r.status.error_message().find("camera"), std::string::npos);
  // A denormal focal length made the ray directions infinite and aborted the ray caster.
  render = ShelfView();
  render.mutable_camera()->set_fx(std::numeric_limits<double>::denorm_min());
  render.add_patterns()->set_solid_level(1.0);
  r = Render(stub_.get(), render);
  EXPECT_EQ(r.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(r.status.error_message().find("fx must be in"), std::string::npos)
      << r.status.error_message();
  render = ShelfView();
  render.add_patterns()->set_solid_level(1.5);
  r = Render(stub_.get(), render);
  EXPECT_EQ(r.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  render = ShelfView();
  render.add_patterns()->mutable_gray_code()->set_bit(12);  // 128 columns need 7 bits
  r = Render(stub_.get(), render);
  EXPECT_EQ(r.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);

  EXPECT_EQ(Truth().SerializeAsString(), before) << "a refused request changed the world";
}

// A 10 kB item name was quoted in full: a client with gRPC's default 8 KB metadata limit
// saw RESOURCE_EXHAUSTED instead of NOT_FOUND.
TEST_F(SimulatorRpcTest, ALongUnknownItemNameGetsAReadableNotFound) {
  const std::string name(10000, 'i');
  grpc::Status s = Load(TaskWithBinA("[\"" + name + "\"]"), 1);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND) << s.error_message();
  EXPECT_NE(s.error_message().find("unknown item \"iii"), std::string::npos);
  EXPECT_LT(s.error_message().size(), 400u) << s.error_message();
  // Any other message quoting it is cut by the runtime to 1 kB.
  s = Load("{\"bin_contents\": {\"" + name + "\": []}}", 1);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_LE(s.error_message().size(), 1024u);
}

// A finite but huge position (2e18 m) reached Embree and aborted the simulator
// (SIGABRT on ray.valid()); every later call was UNAVAILABLE.
TEST_F(SimulatorRpcTest, HugePositionsAreRefusedAndTheSimulatorLivesOn) {
  ASSERT_TRUE(Load(TaskWithBinA("[\"kleenex_tissue_box\"]"), 2).ok());
  sim::ProbeContactRequest probe;
  probe.mutable_x_base_tool()->mutable_position()->set_x(2e18);
  probe.mutable_x_base_tool()->mutable_orientation()->set_w(1.0);
  probe.mutable_direction_tcp()->set_z(1.0);
  probe.set_max_distance_m(1.0);
  sim::ProbeContactResponse contact;
  grpc::Status s;
  {
    grpc::ClientContext ctx;
    s = stub_->ProbeContact(&ctx, probe, &contact);
  }
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("X_base_tool.position"), std::string::npos) << s.error_message();

  sim::RenderPatternsRequest render = ShelfView();
  render.add_patterns()->set_solid_level(1.0);
  render.mutable_x_base_camera()->mutable_position()->set_z(-3e18);
  Rendered r = Render(stub_.get(), render);
  EXPECT_EQ(r.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << r.status.error_message();
  EXPECT_NE(r.status.error_message().find("X_base_camera"), std::string::npos);
  render = ShelfView();
  render.add_patterns()->set_solid_level(1.0);
  render.mutable_x_base_projector()->mutable_position()->set_y(1e19);
  r = Render(stub_.get(), render);
  EXPECT_EQ(r.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << r.status.error_message();
  EXPECT_NE(r.status.error_message().find("X_base_projector"), std::string::npos);

  // The simulator still renders.
  render = ShelfView();
  render.add_patterns()->set_solid_level(1.0);
  r = Render(stub_.get(), render);
  EXPECT_TRUE(r.status.ok()) << r.status.error_message();
  EXPECT_EQ(r.headers.size(), 1u);
}

// A 16384 x 16384 render ran 84 s against a 20 s deadline holding ~4 GB, and a blur of
// sigma 1e6 ran for minutes: both are refused before any work now.
TEST_F(SimulatorRpcTest, RenderPatternsRefusesRequestsBeyondItsLimits) {
  auto expect_refused = [&](const sim::RenderPatternsRequest& req, const std::string& field) {
    const auto start = std::chrono::steady_clock::now();
    const Rendered r = Render(stub_.get(), req);
    EXPECT_EQ(r.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT)
        << field << ": " << r.status.error_message();
    EXPECT_NE(r.status.error_message().find(field), std::string::npos) << r.status.error_message();
    EXPECT_TRUE(r.headers.empty());
    EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(10)) << field;
  };
  auto resize = [](picking::common::v1::CameraIntrinsics* m, int w, int h) {
    m->set_width(w);
    m->set_height(h);
    m->set_cx(0.5 * (w - 1));
    m->set_cy(0.5 * (h - 1));
  };
  sim::RenderPatternsRequest req = ShelfView();
  req.add_patterns()->set_solid_level(1.0);
  resize(req.mutable_camera(), 16384, 16384);
  expect_refused(req, "camera");
  req = ShelfView();
  req.add_patterns()->set_solid_level(1.0);
  resize(req.mutable_camera(), 3000, 3000);  // each side allowed, 9 Mpx is not
  expect_refused(req, "camera");
  req = ShelfView();
  req.add_patterns()->set_solid_level(1.0);
  resize(req.mutable_projector(), 16384, 16384);
  expect_refused(req, "projector");
  req = ShelfView();
  resize(req.mutable_projector(), 2048, 2048);
  for (int i = 0; i < 65; ++i) req.add_patterns()->set_solid_level(1.0);  // 2^28 + 4 Mpx
  expect_refused(req, "patterns");
  req = ShelfView();
  req.add_patterns()->set_solid_level(1.0);
  req.mutable_options()->set_projector_blur_sigma_px(1e6);
  expect_refused(req, "projector_blur_sigma_px");

  // The largest blur is still rendered.
  req.mutable_options()->set_projector_blur_sigma_px(20.0);
  const Rendered r = Render(stub_.get(), req);
  EXPECT_TRUE(r.status.ok()) << r.status.error_message();
  EXPECT_EQ(r.headers.size(), 1u);
}

// A render used to run to its end whatever happened: after SIGTERM the server waited the
// whole grace period for it. It now ends at the next group of images with UNAVAILABLE.
TEST(SimulatorServerTest, ALongRenderEndsWhenTheServerIsAskedToStop) {
  ServerProcess server(ServerBinary(kBinary), {"--shutdown-grace-s=300"});
  auto stub = sim::SimulatorService::NewStub(server.Channel());
  sim::RenderPatternsRequest req = ShelfView();
  auto resize = [](picking::common::v1::CameraIntrinsics* m, int w, int h, double f) {
    m->set_width(w), m->set_height(h), m->set_fx(f), m->set_fy(f);
    m->set_cx(0.5 * (w - 1)), m->set_cy(0.5 * (h - 1));
  };
  resize(req.mutable_camera(), 2048, 2048, 1900.0);
  resize(req.mutable_projector(), 1024, 1024, 880.0);
  constexpr int kPatterns = 64;
  for (int i = 0; i < kPatterns; ++i) req.add_patterns()->set_solid_level((i % 2) ? 1.0 : 0.5);
  req.mutable_options()->set_projector_blur_sigma_px(5.0);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(600));
  auto reader = stub->RenderPatterns(&ctx, req);
  sim::RenderPatternsResponse response;
  ASSERT_TRUE(reader->Read(&response));  // the render is under way
  ASSERT_EQ(::kill(server.pid(), SIGTERM), 0);
  int images = response.chunk().has_header() ? 1 : 0;
  while (reader->Read(&response)) images += response.chunk().has_header() ? 1 : 0;
  const grpc::Status s = reader->Finish();
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAVAILABLE) << s.error_message();
  EXPECT_NE(s.error_message().find("shutting down"), std::string::npos) << s.error_message();
  EXPECT_LT(images, kPatterns);
  EXPECT_EQ(server.Stop(), 0);
}

// ---------------------------------------------------------------------------------------
// RenderDepth: the ground truth of the scanner's camera.

struct DepthImage {
  grpc::Status status;
  std::vector<common::ImageHeader> headers;
  std::vector<float> depth_m;  // The first image's pixels.
  int width = 0;
  float at(int x, int y) const { return depth_m[static_cast<std::size_t>(y) * width + x]; }
};

DepthImage RenderDepth(sim::SimulatorService::Stub* stub, const sim::RenderDepthRequest& req) {
  DepthImage out;
  grpc::ClientContext ctx;
  auto reader = stub->RenderDepth(&ctx, req);
  sim::RenderDepthResponse response;
  std::string bytes;
  while (reader->Read(&response)) {
    const common::ImageChunk& chunk = response.chunk();
    if (chunk.has_header()) out.headers.push_back(chunk.header());
    if (out.headers.size() == 1) bytes += chunk.data();
  }
  out.status = reader->Finish();
  out.depth_m.resize(bytes.size() / sizeof(float));
  std::memcpy(out.depth_m.data(), bytes.data(), out.depth_m.size() * sizeof(float));
  if (!out.headers.empty()) out.width = static_cast<int>(out.headers[0].width());
  return out;
}

sim::RenderDepthRequest DepthRequest(const sim::RenderPatternsRequest& view) {
  sim::RenderDepthRequest req;
  *req.mutable_camera() = view.camera();
  *req.mutable_x_base_camera() = view.x_base_camera();
  return req;
}

TEST_F(SimulatorRpcTest, RenderDepthSeesTheTableTopAtTheCameraHeight) {
  ASSERT_TRUE(Load(TaskJson("pick_layout_1"), 1).ok());
  const sim::GetCellResponse cell = Cell();
  const auto& table = cell.x_base_table().position();
  // ShelfView's camera, with a distorted lens, 0.8 m above the centre of the table's top
  // looking straight down (camera axes in base: x = x, y = -y, z = -z).
  constexpr double kHeightM = 0.8;
  sim::RenderPatternsRequest view = ShelfView();
  auto* pose = view.mutable_x_base_camera();
  pose->mutable_position()->set_x(table.x());
  pose->mutable_position()->set_y(table.y());
  pose->mutable_position()->set_z(table.z() + kHeightM);
  pose->mutable_orientation()->set_w(0.0);
  pose->mutable_orientation()->set_x(1.0);
  pose->mutable_orientation()->set_y(0.0);
  pose->mutable_orientation()->set_z(0.0);
  for (double k : {-0.05, 0.02, 0.001, -0.001, 0.0}) view.mutable_camera()->add_distortion(k);
  const DepthImage depth = RenderDepth(stub_.get(), DepthRequest(view));
  ASSERT_TRUE(depth.status.ok()) << depth.status.error_message();
  ASSERT_EQ(depth.headers.size(), 1u);
  EXPECT_EQ(depth.headers[0].format(), common::PIXEL_FORMAT_FLOAT32);
  EXPECT_EQ(depth.headers[0].name(), "depth");
  EXPECT_EQ(depth.headers[0].width(), 160u);
  EXPECT_EQ(depth.headers[0].height(), 120u);
  ASSERT_EQ(depth.depth_m.size(), 160u * 120u);
  // The 0.6 m square top fills the middle of the view (0.43 m either side at 0.8 m): the
  // top is perpendicular to the optical axis, so every pixel that sees it has the depth
  // kHeightM, whatever the distortion; pixels beyond its edges see lower things (the floor,
  // the pedestal) or nothing.
  std::size_t on_top = 0, beyond = 0;
  for (int y = 0; y < 120; ++y) {
    for (int x = 0; x < 160; ++x) {
      const float d = depth.at(x, y);
      if (std::abs(x - 79.5) < 50 && std::abs(y - 59.5) < 50) {
        ASSERT_NEAR(d, kHeightM, 1e-5) << x << "," << y;
        ++on_top;
      } else if (!(std::abs(d - kHeightM) < 1e-5)) {
        EXPECT_TRUE(std::isnan(d) || d > kHeightM + 0.05) << x << "," << y << ": " << d;
        ++beyond;
      }
    }
  }
  EXPECT_GT(beyond, 1000u);
  std::cout << on_top << " pixels on the table's top, " << beyond << " beyond it\n";
}

TEST_F(SimulatorRpcTest, RenderDepthIsNaNExactlyWhereTheCameraSeesNothing) {
  ASSERT_TRUE(Load(TaskJson("pick_layout_1"), 3).ok());
  // Turned a little up and sideways, so the view shows both the shelf and empty space.
  sim::RenderPatternsRequest view = ShelfView();
  auto* q = view.mutable_x_base_camera()->mutable_orientation();
  q->set_w(0.56);
  q->set_x(-0.44);
  q->set_y(0.56);
  q->set_z(-0.44);
  const double norm = std::sqrt(0.56 * 0.56 * 2 + 0.44 * 0.44 * 2);
  q->set_w(q->w() / norm), q->set_x(q->x() / norm), q->set_y(q->y() / norm),
      q->set_z(q->z() / norm);
  view.mutable_x_base_camera()->mutable_position()->set_z(1.2);
  *view.mutable_x_base_projector() = view.x_base_camera();
  view.add_patterns()->set_solid_level(1.0);
  view.mutable_options()->set_ambient(0.5);  // Lights every surface, even in shadow.
  const Rendered white = Render(stub_.get(), view);
  ASSERT_TRUE(white.status.ok()) << white.status.error_message();
  const DepthImage depth = RenderDepth(stub_.get(), DepthRequest(view));
  ASSERT_TRUE(depth.status.ok()) << depth.status.error_message();
  ASSERT_EQ(depth.depth_m.size(), white.pixels[0].size());
  std::size_t surface = 0, empty = 0;
  for (std::size_t i = 0; i < depth.depth_m.size(); ++i) {
    const auto level = static_cast<unsigned char>(white.pixels[0][i]);
    if (std::isnan(depth.depth_m[i])) {
      EXPECT_EQ(level, 0) << "pixel " << i << " has no depth but shows a surface";
      ++empty;
    } else {
      ++surface;
    }
  }
  std::cout << surface << " pixels see a surface, " << empty << " see nothing\n";
  EXPECT_GT(surface, 1000u);
  EXPECT_GT(empty, 1000u);
}

TEST_F(SimulatorRpcTest, RenderDepthFollowsTheLoadedLayout) {
  // ShelfView's camera, raised to look straight into bin_B (no distortion).
  const sim::GetCellResponse cell = Cell();
  const sim::BinInfo* bin = nullptr;
  for (const auto& b : cell.bins()) {
    if (b.bin() == common::CONTAINER_BIN_B) bin = &b;
  }
  ASSERT_NE(bin, nullptr);
  sim::RenderPatternsRequest view = ShelfView();
  view.mutable_x_base_camera()->mutable_position()->set_y(bin->x_base_bin().position().y());
  view.mutable_x_base_camera()->mutable_position()->set_z(bin->x_base_bin().position().z());
  const sim::RenderDepthRequest request = DepthRequest(view);
  auto render = [&] {
    const DepthImage depth = RenderDepth(stub_.get(), request);
    EXPECT_TRUE(depth.status.ok()) << depth.status.error_message();
    return depth.depth_m;
  };
  auto same = [](const std::vector<float>& a, const std::vector<float>& b) {
    if (a.size() != b.size()) return false;
    for (std::size_t i = 0; i < a.size(); ++i) {
      if (!(a[i] == b[i] || (std::isnan(a[i]) && std::isnan(b[i])))) return false;
    }
    return true;
  };
  ASSERT_TRUE(Load(TaskJson("pick_layout_1"), 3).ok());
  const std::vector<float> with_items = render();
  ASSERT_TRUE(Load(TaskWithBinA("[]"), 1).ok());  // Every bin empty.
  const std::vector<float> empty = render();
  ASSERT_TRUE(Load(TaskJson("pick_layout_1"), 3).ok());
  const std::vector<float> again = render();
  ASSERT_EQ(with_items.size(), 160u * 120u);
  // The items of bin_B stand in front of its back and floor: nearer where they are.
  std::size_t nearer = 0;
  for (std::size_t i = 0; i < empty.size(); ++i) {
    if (with_items[i] < empty[i] - 0.01f || (std::isnan(empty[i]) && !std::isnan(with_items[i]))) {
      ++nearer;
    }
    EXPECT_FALSE(with_items[i] > empty[i] + 1e-4f) << i << ": an item cannot push a surface back";
  }
  EXPECT_GT(nearer, 200u) << "bin_B's items are not seen";
  EXPECT_TRUE(same(with_items, again)) << "the same layout must render the same depth";
  EXPECT_FALSE(same(with_items, empty));
}

TEST_F(SimulatorRpcTest, RenderDepthRefusesBadRequests) {
  const sim::RenderDepthRequest good = DepthRequest(ShelfView());
  auto expect_refused = [&](const sim::RenderDepthRequest& req, const std::string& field) {
    const DepthImage depth = RenderDepth(stub_.get(), req);
    EXPECT_EQ(depth.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << field;
    EXPECT_NE(depth.status.error_message().find(field), std::string::npos)
        << depth.status.error_message();
    EXPECT_TRUE(depth.headers.empty());
  };
  sim::RenderDepthRequest req = good;
  req.mutable_camera()->set_height(0);
  expect_refused(req, "camera");
  req = good;
  req.mutable_camera()->set_width(20000);
  expect_refused(req, "camera");
  req = good;
  req.mutable_camera()->set_width(4096);
  req.mutable_camera()->set_height(4096);  // 16 Mpx: over the 4 Mpx limit
  expect_refused(req, "camera");
  req = good;
  req.mutable_x_base_camera()->mutable_position()->set_x(2e18);
  expect_refused(req, "X_base_camera");
  req = good;
  req.mutable_camera()->set_fx(-1.0);
  expect_refused(req, "camera");
  req = good;
  req.mutable_x_base_camera()->mutable_position()->set_y(std::numeric_limits<double>::quiet_NaN());
  expect_refused(req, "X_base_camera");
  req = good;
  req.mutable_x_base_camera()->mutable_orientation()->set_w(3.0);
  expect_refused(req, "X_base_camera");
  req = good;
  req.clear_x_base_camera();
  expect_refused(req, "X_base_camera");
}

}  // namespace
}  // namespace picking::testing
