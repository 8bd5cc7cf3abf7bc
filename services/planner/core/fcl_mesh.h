#pragma once

// FCL helpers shared by the collision library's .cc files (FCL's headers stay out of the
// public headers).
#include <fcl/fcl.h>

#include <memory>

#include "libs/world/mesh.h"

namespace picking::planner {

using MeshBvh = fcl::BVHModel<fcl::OBBRSSd>;

/// The mesh as an FCL bounding-volume hierarchy (OBB + RSS), vertices in the mesh frame.
std::shared_ptr<MeshBvh> MakeMeshBvh(const world::TriangleMesh& mesh);

}  // namespace picking::planner
