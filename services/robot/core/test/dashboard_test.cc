#include "services/robot/core/dashboard.h"

#include <gtest/gtest.h>

#include "services/robot/core/test/fake_ur_controller.h"

namespace picking::robot {
namespace {

TEST(DashboardTest, CommandsAgainstFakeServer) {
  const ur10::Ur10Kinematics kin(ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10"));
  testing::FakeUrController fake(kin);
  DashboardClient client(
      TcpStream::Connect("127.0.0.1", fake.dashboard_port(), std::chrono::seconds(5)));
  EXPECT_EQ(client.RobotMode(), "POWER_OFF");
  client.PowerOn();
  client.BrakeRelease();
  EXPECT_EQ(client.RobotMode(), "RUNNING");
  EXPECT_EQ(client.SafetyStatus(), "NORMAL");
  client.Stop();
  try {
    client.UnlockProtectiveStop();
    FAIL() << "unlock outside a protective stop must fail";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("Cannot unlock"), std::string::npos) << e.what();
  }
  EXPECT_THROW(client.Send("stop\npower off"), std::invalid_argument);
  EXPECT_EQ(fake.dashboard_commands(),
            (std::vector<std::string>{"robotmode", "power on", "brake release", "robotmode",
                                      "safetystatus", "stop", "unlock protective stop"}));
}

TEST(DashboardTest, WrongGreetingIsAnError) {
  TcpListener listener(0);
  std::thread server([&] {
    try {
      auto s = listener.Accept(std::chrono::seconds(5));
      s->WriteAll("hello\n");
      s->ReadLine(std::chrono::seconds(5));  // until the client closes
    } catch (const StreamError&) {
    }
  });
  {
    EXPECT_THROW(
        DashboardClient(TcpStream::Connect("127.0.0.1", listener.port(), std::chrono::seconds(5))),
        std::runtime_error);
  }
  server.join();
}

}  // namespace
}  // namespace picking::robot
