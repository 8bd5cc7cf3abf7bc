#pragma once

// Conversions between picking::geometry::PointCloud and PCL clouds. This header includes PCL:
// include it only from .cc files that use PCL.

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include "libs/geometry/point_cloud.h"

namespace picking::geometry {

/// Positions only. Width, height and frame_id (as header.frame_id) are kept; is_dense is
/// true when every point is finite.
pcl::PointCloud<pcl::PointXYZ> ToPclXyz(const PointCloud& cloud);

/// Positions and normals (curvature 0). Throws std::invalid_argument when the cloud has no
/// normals.
pcl::PointCloud<pcl::PointNormal> ToPclPointNormal(const PointCloud& cloud);

/// Positions and colours. Throws std::invalid_argument when the cloud has no colours.
pcl::PointCloud<pcl::PointXYZRGB> ToPclXyzRgb(const PointCloud& cloud);

/// Back from PCL: the channels the PCL point type carries; width, height and frame_id kept.
PointCloud FromPcl(const pcl::PointCloud<pcl::PointXYZ>& cloud);
PointCloud FromPcl(const pcl::PointCloud<pcl::PointNormal>& cloud);
PointCloud FromPcl(const pcl::PointCloud<pcl::PointXYZRGB>& cloud);

}  // namespace picking::geometry
