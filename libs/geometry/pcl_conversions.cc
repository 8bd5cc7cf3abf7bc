#include "libs/geometry/pcl_conversions.h"

#include <stdexcept>

#include "libs/geometry/point_cloud_io.h"

namespace picking::geometry {
namespace {

template <typename PointT>
pcl::PointCloud<PointT> Shell(const PointCloud& cloud) {
  ValidatePointCloud(cloud, "point cloud");
  pcl::PointCloud<PointT> out;
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

template <typename PointT>
PointCloud Positions(const pcl::PointCloud<PointT>& cloud) {
  PointCloud out;
  out.points.resize(cloud.points.size());
  for (std::size_t i = 0; i < cloud.points.size(); ++i) {
    out.points[i] = Eigen::Vector3f(cloud.points[i].x, cloud.points[i].y, cloud.points[i].z);
  }
  if (static_cast<std::size_t>(cloud.width) * cloud.height == cloud.points.size()) {
    out.width = cloud.width;
    out.height = cloud.height;
  } else {
    out.width = static_cast<std::uint32_t>(cloud.points.size());
    out.height = 1;
  }
  out.frame_id = cloud.header.frame_id;
  return out;
}

}  // namespace

pcl::PointCloud<pcl::PointXYZ> ToPclXyz(const PointCloud& cloud) {
  return Shell<pcl::PointXYZ>(cloud);
}

pcl::PointCloud<pcl::PointNormal> ToPclPointNormal(const PointCloud& cloud) {
  if (!cloud.has_normals()) {
    throw std::invalid_argument("ToPclPointNormal: the point cloud has no normals");
  }
  auto out = Shell<pcl::PointNormal>(cloud);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    out.points[i].normal_x = cloud.normals[i].x();
    out.points[i].normal_y = cloud.normals[i].y();
    out.points[i].normal_z = cloud.normals[i].z();
    out.points[i].curvature = 0.0f;
  }
  return out;
}

pcl::PointCloud<pcl::PointXYZRGB> ToPclXyzRgb(const PointCloud& cloud) {
  if (!cloud.has_colors()) {
    throw std::invalid_argument("ToPclXyzRgb: the point cloud has no colours");
  }
  auto out = Shell<pcl::PointXYZRGB>(cloud);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    out.points[i].r = cloud.colors[i][0];
    out.points[i].g = cloud.colors[i][1];
    out.points[i].b = cloud.colors[i][2];
    out.points[i].a = 255;
  }
  return out;
}

PointCloud FromPcl(const pcl::PointCloud<pcl::PointXYZ>& cloud) { return Positions(cloud); }

PointCloud FromPcl(const pcl::PointCloud<pcl::PointNormal>& cloud) {
  PointCloud out = Positions(cloud);
  out.normals.resize(cloud.points.size());
  for (std::size_t i = 0; i < cloud.points.size(); ++i) {
    out.normals[i] = Eigen::Vector3f(cloud.points[i].normal_x, cloud.points[i].normal_y,
                                     cloud.points[i].normal_z);
  }
  return out;
}

PointCloud FromPcl(const pcl::PointCloud<pcl::PointXYZRGB>& cloud) {
  PointCloud out = Positions(cloud);
  out.colors.resize(cloud.points.size());
  for (std::size_t i = 0; i < cloud.points.size(); ++i) {
    out.colors[i] = {cloud.points[i].r, cloud.points[i].g, cloud.points[i].b};
  }
  return out;
}

}  // namespace picking::geometry
