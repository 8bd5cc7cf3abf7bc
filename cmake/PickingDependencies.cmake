# Every third-party package the project uses, found once, here. All come from Debian 12's
# packages (scripts/install-deps.sh installs them).
find_package(Threads REQUIRED)
find_package(PkgConfig REQUIRED)
find_package(Protobuf REQUIRED)
find_package(gRPC CONFIG REQUIRED)
find_package(OpenSSL REQUIRED)
find_package(Eigen3 3.3 REQUIRED NO_MODULE)
find_package(nlohmann_json 3 REQUIRED)
find_package(yaml-cpp REQUIRED)
find_package(OpenCV 4 REQUIRED COMPONENTS core imgproc imgcodecs calib3d features2d
             structured_light surface_matching)
# Only the PCL modules the project links; the full set drags in VTK and Qt.
find_package(PCL 1.13 REQUIRED COMPONENTS common io kdtree search features filters
             registration segmentation sample_consensus surface)
find_package(octomap REQUIRED)
find_package(fcl REQUIRED)
find_package(embree 3 REQUIRED)
# Bullet (the simulator's settled layouts): Debian's libbullet-dev ships a pkg-config file;
# its CMake config has relative paths. Single precision, Bullet's default.
pkg_check_modules(BULLET REQUIRED IMPORTED_TARGET GLOBAL bullet)
pkg_check_modules(ARAVIS REQUIRED IMPORTED_TARGET aravis-0.8)
# The viewer's HTTP server (Debian builds it as a library; its flags select the same ABI).
pkg_check_modules(HTTPLIB REQUIRED IMPORTED_TARGET cpp-httplib)
find_package(GTest REQUIRED)
find_package(benchmark REQUIRED)

find_program(PICKING_PROTOC protoc REQUIRED)
find_program(PICKING_GRPC_CPP_PLUGIN grpc_cpp_plugin REQUIRED)

# PCL's imported targets carry its include dirs and definitions; wrap them once so a
# component says `picking::pcl` and never repeats this.
add_library(picking_pcl INTERFACE)
target_include_directories(picking_pcl SYSTEM INTERFACE ${PCL_INCLUDE_DIRS})
target_link_libraries(picking_pcl INTERFACE ${PCL_LIBRARIES})
target_compile_definitions(picking_pcl INTERFACE ${PCL_DEFINITIONS})
add_library(picking::pcl ALIAS picking_pcl)

add_library(picking_opencv INTERFACE)
target_include_directories(picking_opencv SYSTEM INTERFACE ${OpenCV_INCLUDE_DIRS})
target_link_libraries(picking_opencv INTERFACE ${OpenCV_LIBS})
add_library(picking::opencv ALIAS picking_opencv)

add_library(picking_octomap INTERFACE)
target_include_directories(picking_octomap SYSTEM INTERFACE ${OCTOMAP_INCLUDE_DIRS})
target_link_libraries(picking_octomap INTERFACE ${OCTOMAP_LIBRARIES})
add_library(picking::octomap ALIAS picking_octomap)
