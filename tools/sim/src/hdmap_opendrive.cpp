// OpenDRIVE worlds (placeholder until the parser lands).
#include "polmap/schema/errors.hpp"
#include "polmap/sim/world.hpp"

namespace polmap::sim {

std::shared_ptr<World> load_opendrive_world(const std::filesystem::path& path, const SimConfig&,
                                            std::uint64_t, double) {
  throw ValidationError("OpenDRIVE worlds are not supported yet: " + path.string());
}

}  // namespace polmap::sim
