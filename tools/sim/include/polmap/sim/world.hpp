#pragma once
/// @file world.hpp
/// A georeferenced radar world: objects with polarimetric scattering models,
/// the route driven through it, and a spatial index so per-frame queries cost
/// O(visible). Worlds come from procedural presets (urban, industrial, rural),
/// Lanelet2 OSM maps and OpenDRIVE files.
#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "polmap/schema/geo.hpp"
#include "polmap/schema/polarimetry.hpp"
#include "polmap/sim/config.hpp"
#include "polmap/sim/path.hpp"
#include "polmap/sim/scattering.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::sim {

enum class ObjectClass : std::uint8_t {
  LampPole,
  SignPole,
  SignPlate,
  TrafficLight,
  Pole,  ///< generic pole (HD-map "pole", OpenDRIVE pole objects)
  GuardrailPost,
  GuidePost,
  TreeTrunk,
  GuardrailBeam,
  Curbstone,
  RoadBorder,
  Wall,
  Facade,
  FacadeRecess,
  FacadeCorner,
  FenceMesh,
  FencePost,
  Vegetation,
  ParkedCar,
  Bin,
};
std::string_view to_string(ObjectClass c);

/// Dominant scattering mechanism (truth; the processing classifies from covariances).
enum class Mechanism : std::uint8_t { Odd, Even, Mixed, Diffuse, Volume };
std::string_view to_string(Mechanism m);

/// Aspect dependence of a point scatterer.
enum class Aspect : std::uint8_t {
  Isotropic,
  /// Specular lobe around +-normal: gain exp(-a^2 / 2w^2), floored at back_gain (sign plates).
  Specular,
  /// Gain 1 within +-lobe_half of the normal direction, back_gain elsewhere
  /// (guardrail post open side, guide-post reflector, facade recess).
  FrontLobe,
};

/// Polarimetric model of an extended object's sub-scatterers.
enum class ExtendedModel : std::uint8_t {
  EvenDihedral,  ///< fixed dihedral of orientation theta (curbs)
  Surface,       ///< DistributedModel::surface (facades, walls)
  Volume,        ///< DistributedModel::volume (vegetation, fence mesh)
  MixedRandom,   ///< DistributedModel::mixed (guardrail beams)
};

/// One object of the world truth. Geometry: one point or a polyline (world frame).
struct WorldObject {
  std::uint32_t id = 0;
  ObjectClass cls = ObjectClass::Pole;
  Mechanism mechanism = Mechanism::Odd;
  bool permanent = true;
  /// For temporary objects: probability to be present in a drive (hash of seed, id, drive).
  double presence_probability = 1.0;
  /// For temporary objects: where it stands in a drive it is present in varies along this
  /// unit axis, uniformly within +-drive_shift_max_m of geometry_m (hash of seed, id,
  /// drive): a parked car is a different car in the same parking space, a bin is put out
  /// where its owner puts it. 0: the same spot in every drive.
  Eigen::Vector2d drive_shift_axis = Eigen::Vector2d::UnitX();
  double drive_shift_max_m = 0.0;
  std::vector<Eigen::Vector2d> geometry_m;
  /// Per object (points) or per metre (extended objects), dBsm.
  double rcs_dbsm = 0.0;
  /// Where it came from ("procedural", "osm way 123", "xodr object 4", "implied").
  std::string source;
};

/// A point scattering centre of an object.
struct PointScatterer {
  Eigen::Vector2d pos_m = Eigen::Vector2d::Zero();
  ScatteringVector omega{};  ///< normalised, half_span = 1
  float rcs_dbsm = 0.0F;
  Aspect aspect = Aspect::Isotropic;
  float normal_rad = 0.0F;  ///< world-frame direction the lobe points to
  float lobe_rad = 0.0F;    ///< Specular: w; FrontLobe: half width
  float back_gain_db = -20.0F;
  bool two_sided = false;  ///< Specular lobe on both sides (flat plates)
  /// Share of the power re-drawn per frame from a volume model (tree bark, clutter).
  float diffuse_fraction = 0.0F;
  std::uint32_t object = 0;
  float phase_rad = 0.0F;  ///< fixed phase offset of this centre
};

/// A straight piece (<= 8 m) of an extended object: a dense chain of sub-scatterers.
struct LineScatterer {
  Eigen::Vector2d p0_m = Eigen::Vector2d::Zero();
  Eigen::Vector2d p1_m = Eigen::Vector2d::Zero();
  ExtendedModel model = ExtendedModel::Surface;
  float theta_rad = 0.0F;         ///< EvenDihedral fold orientation
  float rcs_per_m_dbsm = -10.0F;  ///< at normal incidence, diffuse part
  /// Diffuse gain cos(alpha)^grazing_exponent, alpha = incidence from the normal.
  float grazing_exponent = 1.0F;
  /// Specular odd-bounce lobe near normal: gain (linear over diffuse), width.
  float specular_gain_db = -100.0F;
  float specular_width_rad = 0.03F;
  bool opaque = false;      ///< hides what is behind it
  bool vegetation = false;  ///< attenuates what is behind it (vegetation_loss_db)
  std::uint32_t object = 0;
};

/// A segment that only occludes (car bodies, tree trunks).
struct OccluderSegment {
  Eigen::Vector2d p0_m = Eigen::Vector2d::Zero();
  Eigen::Vector2d p1_m = Eigen::Vector2d::Zero();
  bool vegetation = false;
  std::uint32_t object = 0;
};

/// Lanes of the route for traffic (lateral offsets from the route, left positive).
struct RoadLayout {
  double oncoming_lane_m = 3.5;
  bool has_same_dir_lane = false;
  double same_dir_lane_m = 3.5;
  double oncoming_per_km = 6.0;
  double same_dir_per_km = 0.0;
  double traffic_max_speed_mps = 14.0;
  double default_max_speed_mps = 15.0;
};

/// The radar world. Immutable after construction; shared by all drives.
class World {
 public:
  World(std::string name, const GeoPoint& origin);

  std::string name;
  tiles::LocalFrame frame;
  Path route;
  /// Stations of traffic lights along the route (stops).
  std::vector<double> light_stations_m;
  RoadLayout road;
  std::vector<WorldObject> objects;  ///< index == id
  std::vector<PointScatterer> points;
  std::vector<LineScatterer> lines;
  std::vector<OccluderSegment> occluders;

  [[nodiscard]] const GeoPoint& origin() const { return frame.origin(); }
  /// Adds an object, returns its id.
  std::uint32_t add_object(WorldObject obj);
  /// Adds an extended object's polyline as LineScatterer pieces of at most 8 m.
  void add_line_pieces(const std::vector<Eigen::Vector2d>& poly, const LineScatterer& proto);

  /// Builds the spatial grid; call once after all scatterers are added.
  void build_index();
  /// Indices of scatterers whose index cell intersects the disc (centre, radius).
  void query(const Eigen::Vector2d& centre, double radius_m, std::vector<std::uint32_t>& points,
             std::vector<std::uint32_t>& lines, std::vector<std::uint32_t>& occluders) const;

  /// Whether object id is present in drive (permanent objects always).
  [[nodiscard]] bool present(std::uint32_t id, int drive, std::uint64_t seed) const;
  /// Where object id stands in drive relative to its geometry_m (WorldObject::
  /// drive_shift_max_m; zero for permanent objects).
  [[nodiscard]] Eigen::Vector2d drive_shift_m(std::uint32_t id, int drive,
                                              std::uint64_t seed) const;

 private:
  static constexpr double kCell = 16.0;
  struct Cell {
    std::vector<std::uint32_t> points, lines, occluders;
  };
  [[nodiscard]] static std::int64_t key(int ix, int iy) {
    return (static_cast<std::int64_t>(ix) << 32) ^ static_cast<std::uint32_t>(iy);
  }
  std::unordered_map<std::int64_t, Cell> grid_;
};

/// Procedural preset request.
struct WorldSpec {
  std::string preset = "urban";  ///< urban | industrial | rural
  double length_m = 1000.0;
  std::uint64_t seed = 1;
  /// Geodetic origin of the world frame (route start).
  GeoPoint origin{50.1109, 8.6821, 100.0};  // Frankfurt
};

/// Builds a procedural world (throws ValidationError for an unknown preset / bad length).
std::shared_ptr<World> make_world(const WorldSpec& spec, const SimConfig& cfg = {});
/// Lanelet2 OSM world (throws IoError / FormatError naming the file).
std::shared_ptr<World> load_lanelet2_world(const std::filesystem::path& path,
                                           const SimConfig& cfg = {}, std::uint64_t seed = 1,
                                           double max_length_m = 0.0);
/// OpenDRIVE world (planView lines/arcs/spirals, objects, signals).
std::shared_ptr<World> load_opendrive_world(const std::filesystem::path& path,
                                            const SimConfig& cfg = {}, std::uint64_t seed = 1,
                                            double max_length_m = 0.0);
/// Dispatch on "urban" | "industrial" | "rural" | *.osm | *.xodr.
std::shared_ptr<World> load_world(const std::string& world, double length_m, std::uint64_t seed,
                                  const SimConfig& cfg = {});

}  // namespace polmap::sim
