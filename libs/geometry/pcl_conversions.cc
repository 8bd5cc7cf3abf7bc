#include "libs/geometry/pcl_conversions.h"

#include "libs/geometry/point_cloud_io.h"

namespace picking::geometry {

pcl::PointCloud<pcl::PointXYZ> ToPclXyz(const PointCloud& cloud) {
  ValidatePointCloud(cloud, "point cloud");
  pcl::PointCloud<pcl::PointXYZ> out;
  out.points.resize(cloud.size());
  out.width = cloud.width;
  out.height = cloud.height;
  out.header.frame_id = cloud.frame_id;
  out.is_dense = true;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3f& p = cloud.points[i];
    out.points[i].x = p.x();
    out.points[i].y = p.y();
    out.points[i].z = p.z();
    if (!p.allFinite()) out.is_dense = false;
  }
  return out;
}

}  // namespace picking::geometry
