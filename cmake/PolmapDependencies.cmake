# Every third-party dependency, found once (Debian bookworm packages, see tools/setup).
find_package(Eigen3 3.4 REQUIRED NO_MODULE)
find_package(GeographicLib REQUIRED)
find_package(SQLite3 REQUIRED)
# libpq (libpq-dev): the PostgreSQL store backend. PostgreSQL::PostgreSQL; no server headers.
find_package(PostgreSQL REQUIRED)
find_package(GDAL REQUIRED)
# Also used by cmake/polmapConfig.cmake.in (find_dependency for consumers).
set(POLMAP_OPENCV_COMPONENTS core imgproc ximgproc imgcodecs)
find_package(OpenCV REQUIRED COMPONENTS ${POLMAP_OPENCV_COMPONENTS})
find_package(nanoflann REQUIRED)
find_package(CGAL REQUIRED)
find_package(nlohmann_json REQUIRED)
find_package(Ceres REQUIRED)
find_package(CLI11 REQUIRED)
find_package(GTest REQUIRED)
find_package(ZLIB REQUIRED)
find_package(Threads REQUIRED)
find_package(PkgConfig REQUIRED)
pkg_check_modules(HTTPLIB REQUIRED IMPORTED_TARGET cpp-httplib)
# Helper targets over libraries without (usable) imported targets. Exported with the
# module libraries (polmap::protozero, polmap::geographiclib, polmap::opencv), as
# static module libraries name them in their link interface; their include dirs and
# libraries are absolute system paths (fine for a Debian package install), the
# OpenCV targets come from find_dependency(OpenCV) in polmapConfig.cmake.
find_path(PROTOZERO_INCLUDE_DIR protozero/pbf_writer.hpp REQUIRED)
add_library(polmap_protozero INTERFACE)
target_include_directories(polmap_protozero SYSTEM INTERFACE ${PROTOZERO_INCLUDE_DIR})
polmap_export_target(polmap_protozero)
add_library(polmap_geographiclib INTERFACE)
target_link_libraries(polmap_geographiclib INTERFACE ${GeographicLib_LIBRARIES})
target_include_directories(polmap_geographiclib SYSTEM INTERFACE ${GeographicLib_INCLUDE_DIRS})
polmap_export_target(polmap_geographiclib)
add_library(polmap_opencv INTERFACE)
target_link_libraries(polmap_opencv INTERFACE ${OpenCV_LIBS})
target_include_directories(polmap_opencv SYSTEM INTERFACE ${OpenCV_INCLUDE_DIRS})
polmap_export_target(polmap_opencv)

find_package(pugixml REQUIRED)
pkg_check_modules(OPENSSL REQUIRED IMPORTED_TARGET openssl)
# zstd: the merged gridmap's sum tiles (3-5x faster than zlib at a better ratio).
pkg_check_modules(ZSTD REQUIRED IMPORTED_TARGET libzstd)
