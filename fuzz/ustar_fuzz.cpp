// Fuzzer: the ustar reader. Any input either throws FormatError or yields flat, unique
// member names whose data lies inside the input; and for every accepted archive GDAL's
// /vsitar/ must list the same members with the same sizes (a disagreement is how one
// upload could show the validator one package and GDAL another).
#include <cpl_string.h>
#include <cpl_vsi.h>

#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <map>
#include <string>

#include "fuzz_seeds.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/schema/errors.hpp"

using namespace polmap;

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const auto dir = fuzz::seed_dir(); !dir.empty()) {
    fuzz::write_seed(dir, "package.tar",
                     mapping::write_ustar({{"manifest.json", "{\"format\": \"polmap\"}"},
                                           {"gridmap.tif", std::string(1300, 'g')},
                                           {"candidates.gpkg", std::string(513, 'c')}}));
    fuzz::write_seed(dir, "empty.tar", mapping::write_ustar({}));
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  std::vector<mapping::TarMemberView> members;
  try {
    members = mapping::read_ustar_views(bytes, "fuzz.tar");
  } catch (const FormatError&) {
    return 0;
  }
  std::map<std::string, std::uint64_t> ours;
  for (const auto& m : members) {
    if (m.name.empty() || m.name.find('/') != std::string::npos) std::abort();
    if (m.data.data() < bytes.data() || m.data.data() + m.data.size() > bytes.data() + size) {
      std::abort();
    }
    if (!ours.emplace(m.name, m.data.size()).second) std::abort();
  }
  // Differential: GDAL's tar reader over the same bytes.
  static std::atomic<int> counter{0};
  const std::string mem = "/vsimem/fuzz_" + std::to_string(counter++) + ".tar";
  VSILFILE* f = VSIFileFromMemBuffer(mem.c_str(), const_cast<GByte*>(data),
                                     static_cast<vsi_l_offset>(size), FALSE);
  if (f == nullptr) std::abort();
  VSIFCloseL(f);
  std::map<std::string, std::uint64_t> gdal;
  const std::string root = "/vsitar/" + mem;
  char** list = VSIReadDir(root.c_str());
  for (char** p = list; p != nullptr && *p != nullptr; ++p) {
    VSIStatBufL st;
    if (VSIStatL((root + "/" + *p).c_str(), &st) == 0 && VSI_ISREG(st.st_mode)) {
      gdal[*p] = static_cast<std::uint64_t>(st.st_size);
    }
  }
  CSLDestroy(list);
  VSIUnlink(mem.c_str());
  if (!ours.empty() && gdal != ours) std::abort();
  return 0;
}
