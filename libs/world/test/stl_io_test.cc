#include "libs/world/stl_io.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "libs/world/mesh_utils.h"
#include "libs/world/ply_mesh_io.h"

namespace picking::world {
namespace {

std::string TempPath(const std::string& name) {
  const auto dir = std::filesystem::temp_directory_path() / "picking_world_test";
  std::filesystem::create_directories(dir);
  return (dir / (std::to_string(::getpid()) + "_" + name)).string();
}

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

std::string ThrowMessage(const std::string& path) {
  try {
    ReadStl(path);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST(StlIoTest, BinaryRoundTripKeepsGeometry) {
  const TriangleMesh box = MakeBox({0.3, 0.2, 0.1});
  const std::string path = TempPath("box.stl");
  WriteStlBinary(path, box);
  EXPECT_EQ(std::filesystem::file_size(path), 84u + 50u * 12u);
  const TriangleMesh back = ReadStl(path);
  ASSERT_EQ(back.num_triangles(), 12u);
  EXPECT_NEAR(SignedVolume(back), SignedVolume(box), 1e-9);
  for (std::size_t t = 0; t < 12; ++t) {
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(back.vertices[back.triangles[t][k]], box.vertices[box.triangles[t][k]]);
    }
  }
}

TEST(StlIoTest, ReadsAscii) {
  const std::string path = TempPath("tri.stl");
  WriteText(path,
            "solid test\n"
            "  facet normal 0 0 1\n    outer loop\n"
            "      vertex 0 0 0\n      vertex 1 0 0\n      vertex 0 1 0\n"
            "    endloop\n  endfacet\n"
            "  facet normal 0 0 1\n    outer loop\n"
            "      vertex 1 0 0\n      vertex 1 1 0\n      vertex 0 1 0.5e0\n"
            "    endloop\n  endfacet\n"
            "endsolid test\n");
  const TriangleMesh mesh = ReadStl(path);
  ASSERT_EQ(mesh.num_triangles(), 2u);
  EXPECT_FLOAT_EQ(mesh.vertices[5].z(), 0.5f);
  EXPECT_EQ(mesh.name, std::to_string(::getpid()) + "_tri");
}

TEST(StlIoTest, BinaryFileWhoseHeaderStartsWithSolidIsReadAsBinary) {
  TriangleMesh box = MakeBox({0.1, 0.1, 0.1});
  box.name = "";
  const std::string path = TempPath("solid_header.stl");
  WriteStlBinary(path, box);
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.write("solid trick", 11);
  }
  EXPECT_EQ(ReadStl(path).num_triangles(), 12u);
}

TEST(StlIoTest, TruncatedFilesGiveClearErrors) {
  const std::string path = TempPath("trunc.stl");
  WriteStlBinary(path, MakeBox({0.1, 0.1, 0.1}));
  std::filesystem::resize_file(path, 84 + 50 * 5 + 10);
  const std::string msg = ThrowMessage(path);
  EXPECT_NE(msg.find("truncated"), std::string::npos) << msg;
  EXPECT_NE(msg.find(path), std::string::npos) << msg;

  std::filesystem::resize_file(path, 40);
  EXPECT_NE(ThrowMessage(path).find("truncated"), std::string::npos);

  WriteText(path, "solid x\n facet normal 0 0 1\n outer loop\n vertex 0 0 0\n vertex 1 0");
  EXPECT_NE(ThrowMessage(path).find("line 5"), std::string::npos) << ThrowMessage(path);
  WriteText(path, "solid x\n facet normal 0 0 1\n outer loop\n vertex 0 0 0\n");
  EXPECT_NE(ThrowMessage(path).find("truncated"), std::string::npos) << ThrowMessage(path);
  EXPECT_NE(ThrowMessage(TempPath("does_not_exist.stl")).find("cannot open"), std::string::npos);
}

TEST(StlIoTest, ReadsTheBundledPodMesh) {
  const TriangleMesh pod = ReadStl(std::string(PICKING_DATA_DIR) + "/apc2016/shelf/pod_lowres.stl");
  EXPECT_EQ(pod.num_triangles(), 10184u);
  const auto b = Bounds(pod);
  EXPECT_NEAR(b.sizes().x(), 0.88, 0.01);
  EXPECT_NEAR(b.sizes().z(), 2.37, 0.01);
}

TEST(PlyIoTest, MeshRoundTripKeepsColoursAndAlbedo) {
  TriangleMesh box = MakeBox({0.1, 0.2, 0.3});
  for (std::size_t i = 0; i < box.vertices.size(); ++i) {
    box.vertex_albedo.push_back(static_cast<float>(i) / 24.0f);
    box.vertex_colors.push_back({static_cast<std::uint8_t>(i), 10, 200});
  }
  const std::string path = TempPath("box.ply");
  WritePly(path, box, "test");
  const TriangleMesh back = ReadPly(path);
  EXPECT_EQ(back.vertices, box.vertices);
  EXPECT_EQ(back.triangles, box.triangles);
  EXPECT_EQ(back.vertex_albedo, box.vertex_albedo);
  EXPECT_EQ(back.vertex_colors, box.vertex_colors);
  std::filesystem::resize_file(path, std::filesystem::file_size(path) - 7);
  EXPECT_THROW(ReadPly(path), std::runtime_error);
}

}  // namespace
}  // namespace picking::world
