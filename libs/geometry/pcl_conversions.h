#pragma once

// Conversion of picking::geometry::PointCloud to a PCL cloud. This header includes PCL:
// include it only from .cc files that use PCL.

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include "libs/geometry/point_cloud.h"

namespace picking::geometry {

/// Positions only. Width, height and frame_id (as header.frame_id) are kept; is_dense is
/// true when every point is finite. Throws std::invalid_argument on an inconsistent cloud
/// (ValidatePointCloud).
pcl::PointCloud<pcl::PointXYZ> ToPclXyz(const PointCloud& cloud);

}  // namespace picking::geometry
