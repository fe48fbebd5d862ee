// The malicious-input corpus (docs/security.md, "Malicious-input corpus and full disk"):
// crafted packages and requests against the real server on loopback. Every row gets the
// status docs/security.md documents for it, within kAnswerBoundS; afterwards the server
// answers /health, the store holds exactly what it held before (drive rows, map versions,
// package files), the upload directory is empty; the process's resident memory grows by
// less than kRssBoundBytes over the corpus run twice, and the second run leaves less than
// kHeapRepeatBoundBytes more allocated than the first.
#include <gdal_priv.h>
#include <gdal_utils.h>
#include <malloc.h>
#include <ogrsf_frmts.h>
#include <sqlite3.h>
#include <zlib.h>

#include <functional>
#include <nlohmann/json.hpp>

#include "mapping_service/server/server_probe.hpp"
#include "mapping_service/server_fixture.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/tiles/tile_key.hpp"
#include "polmap/util/sha256.hpp"

namespace polmap::mapping::testing {
namespace {

using nlohmann::json;

/// Every answer of the corpus within this (an error-path bound, not a benchmark: the
/// slowest row takes well under a second on an idle machine).
constexpr double kAnswerBoundS = 10.0;
/// Growth of the resident set over the corpus, run twice (from after the set-up: three
/// uploads, one build). Measured: 12..15 MiB. The test process uses one malloc arena (below),
/// so the figure is the server's memory; with glibc's default of one arena per thread the
/// worker threads keep 130..150 MiB of freed memory after the rows of large strings, which
/// more passes do not grow (`polmap serve` limits itself to four arenas). Sanitizer
/// builds keep freed memory in quarantine (256 MiB).
#if defined(__SANITIZE_ADDRESS__)  // GCC's macro; clang (the fuzz build) has __has_feature
#define POLMAP_TEST_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define POLMAP_TEST_ASAN 1
#endif
#endif
#if defined(POLMAP_TEST_ASAN)
constexpr std::size_t kRssBoundBytes = std::size_t{48 + 256} << 20;
#else
constexpr std::size_t kRssBoundBytes = std::size_t{48} << 20;
#endif
/// One malloc arena for every thread of this test process, set before any thread starts.
[[maybe_unused]] const int kOneArena = ::mallopt(M_ARENA_MAX, 1);
/// Memory still allocated after the second pass that was not after the first: a leak of
/// 100 KiB per row would show here (measured: 0..2 MiB, threads' malloc caches).
constexpr std::size_t kHeapRepeatBoundBytes = std::size_t{8} << 20;

// ------------------------------------------------------------------ ustar surgery

constexpr std::size_t kBlock = 512;
constexpr std::size_t kModeOff = 100, kSizeOff = 124, kChksumOff = 148, kTypeOff = 156;
constexpr std::size_t kLinkOff = 157, kPrefixOff = 345;

/// Recomputes a header block's checksum (so only the field we broke is wrong).
void fix_checksum(char* h) {
  std::memset(h + kChksumOff, ' ', 8);
  unsigned sum = 0;
  for (std::size_t i = 0; i < kBlock; ++i) sum += static_cast<unsigned char>(h[i]);
  std::snprintf(h + kChksumOff, 8, "%06o", sum);  // 6 digits, NUL, then the space
  h[kChksumOff + 7] = ' ';
}

/// Header block of a member (ustar_header), with `edit` applied and the checksum fixed.
std::string header(const std::string& name, std::uint64_t size,
                   const std::function<void(char*)>& edit = {}) {
  std::string h = ustar_header("placeholder", size);
  std::memset(h.data(), 0, 100);
  std::memcpy(h.data(), name.data(), std::min<std::size_t>(name.size(), 100));
  if (edit) edit(h.data());
  fix_checksum(h.data());
  return h;
}

/// A member: header, data, zero padding.
std::string member(const std::string& name, std::string_view data,
                   const std::function<void(char*)>& edit = {}) {
  std::string m = header(name, data.size(), edit);
  m.append(data);
  m.append(ustar_padding(data.size()), '\0');
  return m;
}

std::string end_marker() { return std::string(kUstarEndBytes, '\0'); }

/// The archive with the header of member `index` edited (checksum fixed).
std::string edit_header(std::string tar, std::size_t index,
                        const std::function<void(char*)>& edit) {
  std::size_t off = 0;
  for (std::size_t i = 0; i < index; ++i) {
    const std::uint64_t size = std::strtoull(tar.c_str() + off + kSizeOff, nullptr, 8);
    off += kBlock + (size + kBlock - 1) / kBlock * kBlock;
  }
  edit(tar.data() + off);
  fix_checksum(tar.data() + off);
  return tar;
}

std::string data_of(const std::string& tar, const std::string& name) {
  for (const auto& m : read_ustar(tar)) {
    if (m.name == name) return m.data;
  }
  ADD_FAILURE() << "no member " << name;
  return {};
}

/// gzip (RFC 1952) of bytes.
std::string gzip(std::string_view bytes) {
  z_stream z{};
  EXPECT_EQ(deflateInit2(&z, 6, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY), Z_OK);
  std::string out(deflateBound(&z, bytes.size()) + 32, '\0');
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(bytes.data()));
  z.avail_in = static_cast<uInt>(bytes.size());
  z.next_out = reinterpret_cast<Bytef*>(out.data());
  z.avail_out = static_cast<uInt>(out.size());
  EXPECT_EQ(deflate(&z, Z_FINISH), Z_STREAM_END);
  out.resize(z.total_out);
  deflateEnd(&z);
  return out;
}

// ------------------------------------------------------------------ package surgery

/// The package with its manifest edited by `fn` (the files keep their hashes).
std::string with_manifest(const std::string& tar, const std::function<void(json&)>& fn) {
  auto members = read_ustar(tar);
  for (auto& m : members) {
    if (m.name == "manifest.json") {
      json j = json::parse(m.data);
      fn(j);
      m.data = j.dump(2);
    }
  }
  return write_ustar(members);
}

/// The package with manifest.json replaced by `text` verbatim.
std::string with_manifest_text(const std::string& tar, std::string text) {
  auto members = read_ustar(tar);
  for (auto& m : members) {
    if (m.name == "manifest.json") m.data = std::move(text);
  }
  return write_ustar(members);
}

/// The manifest as text with `key`'s value replaced by `raw` (JSON text, spliced in).
std::string manifest_with_raw(const std::string& tar, const std::string& key,
                              const std::string& raw) {
  json j = json::parse(data_of(tar, "manifest.json"));
  j[key] = "@@RAW@@";
  std::string text = j.dump();
  text.replace(text.find("\"@@RAW@@\""), 9, raw);
  return text;
}

/// The package with member `name` replaced by `data` and the manifest's size and sha256 of
/// it updated: only the member's content is wrong, not its bookkeeping.
std::string with_member(const std::string& tar, const std::string& name, std::string data,
                        const std::function<void(json&)>& manifest_edit = {}) {
  auto members = read_ustar(tar);
  for (auto& m : members) {
    if (m.name == name) m.data = data;
  }
  for (auto& m : members) {
    if (m.name != "manifest.json") continue;
    json j = json::parse(m.data);
    for (auto& f : j["files"]) {
      if (f["name"] == name) {
        f["size_bytes"] = data.size();
        f["sha256"] = util::sha256_hex(data);
      }
    }
    if (manifest_edit) manifest_edit(j);
    m.data = j.dump(2);
  }
  return write_ustar(members);
}

/// A scratch file for GDAL and SQLite to work on.
class Scratch {
 public:
  Scratch() : dir_(polmap::test::unique_test_dir("corpus-scratch")) {}
  [[nodiscard]] std::filesystem::path file(const std::string& name, std::string_view bytes) const {
    util::write_file_bytes(dir_.path() / name, bytes);
    return dir_.path() / name;
  }
  [[nodiscard]] const std::filesystem::path& dir() const { return dir_.path(); }

 private:
  util::ScopedTempDir dir_;
};

/// candidates.gpkg after `sql` ran on it (sqlite3 C API, as a hostile uploader would),
/// optionally after `points_to_add` copies of its first point were added through GDAL
/// (whose R-tree triggers need GDAL's SQL functions).
std::string gpkg_after_sql(const std::string& tar, const std::string& sql, int points_to_add = 0) {
  const Scratch s;
  const auto path = s.file("candidates.gpkg", data_of(tar, "candidates.gpkg"));
  if (points_to_add > 0) {
    GDALAllRegister();
    GDALDatasetUniquePtr ds(GDALDataset::Open(path.c_str(), GDAL_OF_VECTOR | GDAL_OF_UPDATE));
    EXPECT_TRUE(ds);
    OGRLayer* l = ds->GetLayerByName("points");
    std::unique_ptr<OGRFeature> f(l->GetFeature(1));
    for (int k = 0; k < points_to_add; ++k) {
      f->SetFID(OGRNullFID);
      EXPECT_EQ(l->CreateFeature(f.get()), OGRERR_NONE);
    }
  }
  sqlite3* db = nullptr;
  EXPECT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  char* err = nullptr;
  EXPECT_EQ(sqlite3_exec(db, sql.c_str(), nullptr, nullptr, &err), SQLITE_OK)
      << (err ? err : "") << " in " << sql;
  sqlite3_free(err);
  sqlite3_close(db);
  return util::read_file_bytes(path);
}

/// gridmap.tif rewritten by gdal_translate with `args`.
std::string tiff_translated(const std::string& tar, const std::vector<std::string>& args) {
  GDALAllRegister();
  const Scratch s;
  const auto in = s.file("in.tif", data_of(tar, "gridmap.tif"));
  const auto out = s.dir() / "out.tif";
  std::vector<char*> argv;
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  GDALTranslateOptions* opt = GDALTranslateOptionsNew(argv.data(), nullptr);
  GDALDatasetH src = GDALOpen(in.c_str(), GA_ReadOnly);
  GDALDatasetH dst = GDALTranslate(out.c_str(), src, opt, nullptr);
  EXPECT_NE(dst, nullptr);
  GDALClose(dst);
  GDALClose(src);
  GDALTranslateOptionsFree(opt);
  return util::read_file_bytes(out);
}

/// A decompression bomb: a w x h GeoTIFF laid out as the package's (bands, names, CRS,
/// origin, 256 x 256 DEFLATE tiles) but sparse: no block is written, so the file holds
/// only its tile index while every block reads back as zeros.
std::string sparse_tiff(const std::string& tar, int w, int h) {
  GDALAllRegister();
  const Scratch s;
  const auto in = s.file("in.tif", data_of(tar, "gridmap.tif"));
  const auto out = s.dir() / "bomb.tif";
  GDALDatasetUniquePtr src(GDALDataset::Open(in.c_str(), GDAL_OF_RASTER));
  const char* opts[] = {"TILED=YES",      "BLOCKXSIZE=256", "BLOCKYSIZE=256", "COMPRESS=DEFLATE",
                        "SPARSE_OK=TRUE", "BIGTIFF=NO",     nullptr};
  GDALDriver* gtiff = GetGDALDriverManager()->GetDriverByName("GTiff");
  GDALDatasetUniquePtr dst(gtiff->Create(out.c_str(), w, h, src->GetRasterCount(), GDT_Float32,
                                         const_cast<char**>(opts)));
  EXPECT_TRUE(dst);
  double gt[6];
  src->GetGeoTransform(gt);
  dst->SetGeoTransform(gt);
  dst->SetSpatialRef(src->GetSpatialRef());
  for (int b = 1; b <= src->GetRasterCount(); ++b) {
    dst->GetRasterBand(b)->SetDescription(src->GetRasterBand(b)->GetDescription());
  }
  dst.reset();
  return util::read_file_bytes(out);
}

// ------------------------------------------------------------------ requests

std::string key_header() {
  // Appended, not `std::string(...) + kKey + ...`: GCC 12 at -O3 reports a false
  // -Warray-bounds inside std::string's move constructor for that chain.
  std::string h = "Authorization: Bearer ";
  h += kKey;
  h += "\r\n";
  return h;
}

std::string upload_request(const std::string& body, const std::string& extra_headers = {}) {
  return "POST /v1/drives HTTP/1.1\r\nHost: corpus\r\n" + key_header() +
         "Content-Type: application/x-tar\r\nContent-Length: " + std::to_string(body.size()) +
         "\r\n" + extra_headers + "Connection: close\r\n\r\n" + body;
}

std::string get_request(const std::string& target, const std::string& extra_headers = {}) {
  return "GET " + target + " HTTP/1.1\r\nHost: corpus\r\n" + extra_headers +
         "Connection: close\r\n\r\n";
}

std::string json_post(const std::string& target, const std::string& body) {
  return "POST " + target + " HTTP/1.1\r\nHost: corpus\r\n" + key_header() +
         "Content-Type: application/json\r\nContent-Length: " + std::to_string(body.size()) +
         "\r\nConnection: close\r\n\r\n" + body;
}

// ------------------------------------------------------------------ the corpus

/// One crafted input and what docs/security.md says the server answers.
struct Row {
  std::string name;
  std::string request;    ///< raw HTTP bytes, sent on a new connection
  int expected = 0;       ///< the documented status
  std::string reply_has;  ///< a part of the reply that shows why (empty: any)
};

/// The valid package every package row is a mutation of (not uploaded itself).
const std::string& base_tar() {
  static const std::string tar = [] {
    const util::ScopedTempDir base(polmap::test::unique_test_dir("corpus-base"));
    return pack_drive_package(write_scene_package(base.path(), "corpus_base", 21));
  }();
  return tar;
}

std::vector<Row> package_rows() {
  const std::string& tar = base_tar();
  const std::string manifest = data_of(tar, "manifest.json");
  const std::string gridmap = data_of(tar, "gridmap.tif");
  const std::string gpkg = data_of(tar, "candidates.gpkg");
  const std::string mb10(10u << 20, 'a');
  auto archive = [&](std::initializer_list<std::string> parts) {
    std::string a;
    for (const auto& p : parts) a += p;
    return a;
  };
  auto typed = [](char type) { return [type](char* h) { h[kTypeOff] = type; }; };
  std::vector<Row> rows;
  auto add = [&](std::string name, const std::string& body, int status, std::string has) {
    rows.push_back({std::move(name), upload_request(body), status, std::move(has)});
  };

  // The ustar container: one parser, and it refuses what another reader could read
  // differently.
  add("ustar: size field not octal", edit_header(tar, 0, [](char* h) { h[kSizeOff + 5] = '9'; }),
      400, "unreadable size field");
  add("ustar: mode field not octal",
      edit_header(tar, 1, [](char* h) { std::memcpy(h + kModeOff, "0064x4 ", 7); }), 400,
      "unreadable mode field");
  add("ustar: base-256 size field",
      edit_header(tar, 0, [](char* h) { h[kSizeOff] = static_cast<char>(0x80); }), 400,
      "unreadable size field");
  add("ustar: symbolic link member",
      archive({member("manifest.json", manifest), member("gridmap.tif", gridmap),
               member("candidates.gpkg", "",
                      [](char* h) {
                        h[kTypeOff] = '2';
                        std::memcpy(h + kLinkOff, "/etc/passwd", 11);
                      }),
               end_marker()}),
      400, "unsupported tar entry type '2'");
  add("ustar: hard link member",
      archive({member("manifest.json", manifest), member("gridmap.tif", gridmap),
               member("candidates.gpkg", "",
                      [](char* h) {
                        h[kTypeOff] = '1';
                        std::memcpy(h + kLinkOff, "manifest.json", 13);
                      }),
               end_marker()}),
      400, "unsupported tar entry type '1'");
  add("ustar: ../ in a member name",
      archive({member("../manifest.json", manifest), member("gridmap.tif", gridmap),
               member("candidates.gpkg", gpkg), end_marker()}),
      400, "not a flat, printable file name");
  add("ustar: absolute member name",
      archive({member("/etc/manifest.json", manifest), member("gridmap.tif", gridmap),
               member("candidates.gpkg", gpkg), end_marker()}),
      400, "not a flat, printable file name");
  add("ustar: directory in the prefix field",
      archive({member("manifest.json", manifest,
                      [](char* h) { std::memcpy(h + kPrefixOff, "pkg", 3); }),
               member("gridmap.tif", gridmap), member("candidates.gpkg", gpkg), end_marker()}),
      400, "not a flat, printable file name");
  const std::string pax = "30 path=candidates.gpkg.shadow\n";
  add("ustar: PAX extended header renaming the next member",
      archive({member("manifest.json", manifest), member("gridmap.tif", gridmap),
               member("PaxHeader", pax, typed('x')), member("candidates.gpkg", gpkg),
               end_marker()}),
      400, "unsupported tar entry type 'x'");
  add("ustar: PAX global header",
      archive({member("GlobalHead", pax, typed('g')), member("manifest.json", manifest),
               member("gridmap.tif", gridmap), member("candidates.gpkg", gpkg), end_marker()}),
      400, "unsupported tar entry type 'g'");
  add("ustar: GNU long name",
      archive({member("././@LongLink", std::string(200, 'n') + '\0', typed('L')),
               member("manifest.json", manifest), member("gridmap.tif", gridmap),
               member("candidates.gpkg", gpkg), end_marker()}),
      400, "unsupported tar entry type 'L'");
  add("ustar: data after the end marker", tar + member("candidates.gpkg", gpkg) + end_marker(), 400,
      "data after the end-of-archive marker");
  add("ustar: duplicate member",
      archive({member("manifest.json", manifest), member("gridmap.tif", gridmap),
               member("candidates.gpkg", gpkg), member("manifest.json", manifest), end_marker()}),
      400, "duplicate member");
  add(
      "ustar: header checksum wrong",
      [&] {
        std::string t = tar;
        t[10] ^= 1;  // a byte of the first member's name, checksum left as it was
        return t;
      }(),
      400, "checksum mismatch");
  add("ustar: declared size beyond the archive",
      edit_header(tar, 2, [](char* h) { std::memcpy(h + kSizeOff, "77777777777", 11); }), 400,
      "truncated archive");
  add("ustar: no end-of-archive marker", tar.substr(0, tar.size() - kUstarEndBytes), 400,
      "missing end-of-archive marker");
  add("ustar: control character in a member name",
      archive({member("manifest.json\x1b[2J", manifest), member("gridmap.tif", gridmap),
               member("candidates.gpkg", gpkg), end_marker()}),
      400, "not a flat, printable file name");
  add("gzip-compressed archive", gzip(tar), 400, "archive");

  // Members that are not the package's three files.
  for (const std::string extra :
       {"gridmap.tif.aux.xml", "candidates.gpkg-journal", "candidates.gpkg-wal"}) {
    add("extra member " + extra,
        archive({member("manifest.json", manifest), member("gridmap.tif", gridmap),
                 member("candidates.gpkg", gpkg), member(extra, "<PAMDataset/>"), end_marker()}),
        422, "unexpected member '" + extra + "'");
  }
  // Another format under the expected name: only the GTiff driver, and SQLite's screen before
  // the GPKG driver, ever see them.
  add("OGR VRT named candidates.gpkg",
      with_member(tar, "candidates.gpkg",
                  "<OGRVRTDataSource><OGRVRTLayer name=\"points\"><SrcDataSource>/etc/passwd"
                  "</SrcDataSource></OGRVRTLayer></OGRVRTDataSource>"),
      400, "not a SQLite 3 database");
  add("GeoJSON named candidates.gpkg",
      with_member(tar, "candidates.gpkg", R"({"type":"FeatureCollection","features":[]})"), 400,
      "not a SQLite 3 database");
  add("VRT named gridmap.tif",
      with_member(tar, "gridmap.tif",
                  "<VRTDataset rasterXSize=\"300\" rasterYSize=\"280\"><VRTRasterBand "
                  "dataType=\"Float32\" band=\"1\"><SimpleSource><SourceFilename>/etc/shadow"
                  "</SourceFilename></SimpleSource></VRTRasterBand></VRTDataset>"),
      400, "not a readable GeoTIFF");

  // GeoPackages with more than GDAL's writer creates: refused by the SQLite screen, which
  // names the object.
  add("GeoPackage with a view",
      with_member(tar, "candidates.gpkg",
                  gpkg_after_sql(tar, "CREATE VIEW points_copy AS SELECT * FROM points")),
      422, "points_copy");
  add("GeoPackage with a trigger",
      with_member(tar, "candidates.gpkg",
                  gpkg_after_sql(tar,
                                 "CREATE TRIGGER wipe AFTER UPDATE ON gpkg_ogr_contents BEGIN "
                                 "DELETE FROM points; END")),
      422, "wipe");
  add("GeoPackage with an extra table",
      with_member(tar, "candidates.gpkg",
                  gpkg_after_sql(tar,
                                 "CREATE TABLE stowaway(payload BLOB); INSERT INTO stowaway "
                                 "VALUES (zeroblob(100000))")),
      422, "stowaway");
  add("GeoPackage whose gpkg_ogr_contents hides 5 added points",
      with_member(tar, "candidates.gpkg",
                  gpkg_after_sql(tar,
                                 "UPDATE gpkg_ogr_contents SET feature_count = feature_count - 5 "
                                 "WHERE table_name = 'points'",
                                 5)),
      422, "manifest.json counts say");

  // GeoTIFFs unlike the manifest.
  add("GeoTIFF with 128 x 128 blocks",
      with_member(tar, "gridmap.tif",
                  tiff_translated(tar, {"-co", "TILED=YES", "-co", "BLOCKXSIZE=128", "-co",
                                        "BLOCKYSIZE=128", "-co", "COMPRESS=DEFLATE"})),
      422, "block size 128x128");
  add("GeoTIFF with Float64 bands",
      with_member(tar, "gridmap.tif",
                  tiff_translated(tar, {"-ot", "Float64", "-co", "TILED=YES", "-co",
                                        "BLOCKXSIZE=256", "-co", "BLOCKYSIZE=256"})),
      422, "data type Float64");
  add("GeoTIFF in strips",
      with_member(tar, "gridmap.tif", tiff_translated(tar, {"-co", "TILED=NO"})), 422,
      "expected 256x256 tiles");
  {
    // 30000 x 30000 cells of 10 bands (36 GB as Float32) in a 1.1 MB file. Valid but for
    // the candidates, which lie where no cell is observed: 422. Unwritten blocks are zeros
    // and not read (reading them took 17-20 s for this one, 92 s for 50000 x 50000).
    static constexpr int kSide = 30000;
    add("GeoTIFF decompression bomb (sparse 30000 x 30000 of zeros)",
        with_member(tar, "gridmap.tif", sparse_tiff(tar, kSide, kSide),
                    [](json& j) {
                      j["gridmap"]["width"] = kSide;
                      j["gridmap"]["height"] = kSide;
                    }),
        422, "points");
  }

  // Manifests with huge numbers, deep nesting, long strings.
  add("manifest: gridmap 1000001 cells wide",
      with_manifest(tar, [](json& j) { j["gridmap"]["width"] = 1000001; }), 422,
      "outside [1, 1000000] cells");
  add("manifest: a count of 2^64 - 1",
      with_manifest(tar,
                    [](json& j) { j["counts"]["points"] = std::uint64_t{18446744073709551615u}; }),
      422, "integer out of range");
  add("manifest: 1e400", with_manifest_text(tar, manifest_with_raw(tar, "distance_m", "1e400")),
      400, "number overflow");
  add("manifest: cell size 1e308", with_manifest(tar, [](json& j) { j["cell_size_m"] = 1e308; }),
      422, "cell_size_m");
  add("manifest: a million nested arrays (2 MB)",
      with_manifest_text(tar, std::string(1'000'000, '[') + std::string(1'000'000, ']')), 422,
      "manifest.json: larger than");
  add("manifest: 400000 nested arrays (under the size cap)",
      with_manifest_text(tar, std::string(400'000, '[') + std::string(400'000, ']')), 400,
      "expected a JSON object");
  add(
      "manifest: 100000 nested objects as format_version",
      [&] {
        std::string deep;
        for (int i = 0; i < 100'000; ++i) deep += "{\"a\":";
        deep += "0";
        deep += std::string(100'000, '}');
        return with_manifest_text(tar, manifest_with_raw(tar, "format_version", deep));
      }(),
      400, "format_version");
  // 10 MB strings: over the manifest's size cap, refused before it is parsed; just under
  // it, refused by the field's own check.
  for (const char* field : {"drive_id", "crs_proj", "producer", "world"}) {
    add(std::string("manifest: 10 MB ") + field,
        with_manifest(tar, [&](json& j) { j[field] = mb10; }), 422, "manifest.json: larger than");
  }
  add("manifest: 1000000-byte drive_id",
      with_manifest(tar, [&](json& j) { j["drive_id"] = std::string(1'000'000, 'd'); }), 422,
      "field 'drive_id'");
  add("manifest: 1000000-byte crs_proj",
      with_manifest(tar, [&](json& j) { j["crs_proj"] = std::string(1'000'000, 'c'); }), 422,
      "field 'crs_proj'");
  // fuzz_package: PROJ's user-input parser searched its database for > 10 s on this name;
  // crs_proj is now parsed without PROJ. File paths and URLs must not be opened either.
  for (const char* crs : {"+proj;tmerc +lat_0=35.224 +lon_0=138.8045 +k=1 +x_0=0 +y_0=0 "
                          "+ellps=WGS84 +units=m +no_defs",
                          "/etc/passwd", "http://127.0.0.1:9/crs.wkt", "EPSG:4326"}) {
    add(std::string("manifest: crs_proj '") + crs + "'",
        with_manifest(tar, [&](json& j) { j["crs_proj"] = crs; }), 422, "field 'crs_proj'");
  }
  add("manifest: NUL in drive_id",
      with_manifest(tar, [](json& j) { j["drive_id"] = std::string("corpus\0base", 11); }), 422,
      "drive_id");
  add("manifest: invalid UTF-8",
      with_manifest_text(tar, manifest_with_raw(tar, "world", "\"\xff\xfe\"")), 400,
      "not valid JSON");
  return rows;
}

std::vector<Row> request_rows(const tiles::TileKey& tile) {
  const std::string tile_path = "/v1/tiles/" + tiles::to_string(tile);
  std::vector<Row> rows;
  auto add = [&](std::string name, std::string request, int status, std::string has) {
    rows.push_back({std::move(name), std::move(request), status, std::move(has)});
  };
  std::string ranges = "Range: bytes=0-0";
  for (int i = 1; i < 1500; ++i) {
    ranges += ',';
    ranges += std::to_string(2 * i);
    ranges += '-';
    ranges += std::to_string(2 * i);
  }
  // (cpp-httplib turns the 416's body into an empty multipart/byteranges one.)
  add("1500 byte ranges", get_request(tile_path, ranges.substr(0, 8000) + "\r\n"), 416, "");
  add("a Range header line over 8 KiB", get_request(tile_path, ranges + "\r\n"), 400, "");
  std::string many;
  for (int i = 0; i < 1000; ++i) {
    many += "X-F";
    many += std::to_string(i);
    many += ": y\r\n";
  }
  add("1000 header fields", get_request("/health", many), 431, "header");
  add("a header line over 8 KiB",
      get_request("/health", "X-Big: " + std::string(9000, 'b') + "\r\n"), 400, "");
  std::string big;
  for (int i = 0; i < 6; ++i) {
    big += "X-Big-";
    big += std::to_string(i);
    big += ": " + std::string(7000, 'b') + "\r\n";
  }
  add("42 KiB of headers in 6 lines", get_request("/health", big), 431, "header");
  add("request target of 10 KiB", get_request("/v1/tiles/16/1/1?x=" + std::string(10240, 'q')), 414,
      "");

  const std::string gig = "Content-Length: 1073741824\r\n";
  add("unauthenticated 1 GiB upload",
      "POST /v1/drives HTTP/1.1\r\nHost: c\r\nContent-Type: application/x-tar\r\n" + gig +
          "Connection: close\r\n\r\n",
      401, "Authorization");
  add("1 GiB upload with a key",
      "POST /v1/drives HTTP/1.1\r\nHost: c\r\n" + key_header() +
          "Content-Type: application/x-tar\r\n" + gig + "Connection: close\r\n\r\n",
      413, "upload limit");
  add("unauthenticated 1 GiB build request",
      "POST /v1/maps HTTP/1.1\r\nHost: c\r\nContent-Type: application/json\r\n" + gig +
          "Connection: close\r\n\r\n",
      401, "Authorization");
  add("unauthenticated chunked build request",
      "POST /v1/maps HTTP/1.1\r\nHost: c\r\nTransfer-Encoding: chunked\r\nConnection: "
      "close\r\n\r\n",
      401, "Authorization");
  add("unauthenticated upload with Content-Length and chunked",
      "POST /v1/drives HTTP/1.1\r\nHost: c\r\nContent-Length: 10\r\nTransfer-Encoding: "
      "chunked\r\nConnection: close\r\n\r\n",
      401, "Authorization");
  add("chunked upload with a key and a broken chunk size",
      "POST /v1/drives HTTP/1.1\r\nHost: c\r\n" + key_header() +
          "Content-Type: application/x-tar\r\nTransfer-Encoding: chunked\r\nConnection: "
          "close\r\n\r\nzz\r\nhello\r\n0\r\n\r\n",
      400, "interrupted");
  // Expect: 100-continue: refused requests are answered instead of being invited to send.
  const std::string expect = "Expect: 100-continue\r\n";
  add("unauthenticated upload with Expect: 100-continue",
      "POST /v1/drives HTTP/1.1\r\nHost: c\r\nContent-Type: application/x-tar\r\n" + expect + gig +
          "Connection: close\r\n\r\n",
      401, "Authorization");
  add("1 GiB upload with a key and Expect: 100-continue",
      "POST /v1/drives HTTP/1.1\r\nHost: c\r\n" + key_header() +
          "Content-Type: application/x-tar\r\n" + expect + gig + "Connection: close\r\n\r\n",
      413, "upload limit");
  add("unauthenticated build request with Expect: 100-continue",
      "POST /v1/maps HTTP/1.1\r\nHost: c\r\nContent-Type: application/json\r\n" + expect +
          "Content-Length: 2\r\nConnection: close\r\n\r\n",
      401, "Authorization");
  add("an Authorization header of 7 KiB",
      "POST /v1/drives HTTP/1.1\r\nHost: c\r\nAuthorization: Bearer " + std::string(7000, 'k') +
          "\r\nContent-Length: 1\r\nConnection: close\r\n\r\nx",
      401, "invalid API key");
  add("gzip upload with a key",
      "POST /v1/drives HTTP/1.1\r\nHost: c\r\n" + key_header() +
          "Content-Type: application/x-tar\r\nContent-Encoding: gzip\r\nContent-Length: "
          "10\r\nConnection: close\r\n\r\n0123456789",
      415, "Content-Encoding");
  add("deflate Content-Encoding on a GET", get_request("/health", "Content-Encoding: deflate\r\n"),
      415, "Content-Encoding");
  add("negative Content-Length with a key",
      "POST /v1/maps HTTP/1.1\r\nHost: c\r\n" + key_header() +
          "Content-Length: -1\r\nConnection: close\r\n\r\n",
      413, "");
  add("Content-Length not a number with a key",
      "POST /v1/maps HTTP/1.1\r\nHost: c\r\n" + key_header() +
          "Content-Length: 1e9\r\nConnection: close\r\n\r\n",
      413, "");

  add("unknown method", "FROB /health HTTP/1.1\r\nHost: c\r\nConnection: close\r\n\r\n", 400, "");
  add("PUT of a drive",
      "PUT /v1/drives HTTP/1.1\r\nHost: c\r\nContent-Length: 0\r\nConnection: close\r\n\r\n", 404,
      "no such endpoint");
  add("TRACE", "TRACE / HTTP/1.1\r\nHost: c\r\nConnection: close\r\n\r\n", 400, "");
  add("request line without a version", "GET /health\r\n\r\n", 400, "");
  add("%00 in a drive id", get_request("/v1/drives/%00", key_header()), 404, "does not exist");
  add("%00 in a tile address", get_request("/v1/tiles/16/1%00/2"), 400, "malformed");
  add("control characters in the path", get_request("/v1/\x01\x1b[31m\x7f"), 404,
      "no such endpoint");
  add("tile x = 2^16 at zoom 16", get_request("/v1/tiles/16/65536/0"), 400, "malformed");
  add("tile zoom 10^20", get_request("/v1/tiles/100000000000000000000/0/0"), 400, "malformed");
  add("MVT zoom 25", get_request("/v1/mvt/25/0/0.mvt"), 400, "malformed");
  add("negative gridmap tile", get_request("/v1/gridmap/16/-1/0.png"), 400, "malformed");
  add("hexadecimal tile address", get_request("/v1/tiles/16/0x10/1"), 400, "malformed");
  add("version 10^20", get_request(tile_path + "?version=100000000000000000000"), 400, "version");
  add("export bbox of 1e308 degrees",
      get_request("/v1/export?format=geojson&bbox=-1e308,-90,1e308,90", key_header()), 400, "bbox");
  add("export bbox of NaN",
      get_request("/v1/export?format=geojson&bbox=nan,nan,nan,nan", key_header()), 400, "bbox");
  add("export bbox of 1e999",
      get_request("/v1/export?format=geojson&bbox=1e999,0,1,1", key_header()), 400, "bbox");
  add("build region of 1e308 degrees",
      json_post("/v1/maps", R"({"region": [-1e308, -1e308, 1e308, 1e308]})"), 422, "region");
  add("build request with a number of 1e400", json_post("/v1/maps", R"({"notes": 1e400})"), 400,
      "not JSON");
  add("build request of a million nested arrays",
      json_post("/v1/maps", std::string(500'000, '[') + std::string(500'000, ']')), 400,
      "JSON object");
  {
    json ex = json::array();
    for (int i = 0; i < 50'000; ++i) {
      std::string id = "ghost";
      id += std::to_string(i);
      ex.push_back(id);
    }
    add("build request excluding 50000 unknown drives",
        json_post("/v1/maps", json{{"exclude_drives", ex}}.dump()), 422, "exclude_drives[0]");
  }
  // Localization run reports (POST /v1/runs, schema/localization_run.md).
  add("run report of a million nested arrays",
      json_post("/v1/runs", std::string(500'000, '[') + std::string(500'000, ']')), 400, "nested");
  add("run report with a number of 1e400",
      json_post("/v1/runs", R"({"format": "polmap-localization-run", "version": 1e400})"), 400,
      "not JSON");
  {
    std::string many = R"({"format":"polmap-localization-run","version":1,"map_version":1,)"
                       R"("pol":"full","reference":"none","samples":[)";
    for (int i = 0; i < 150'000; ++i) many += i ? ",{}" : "{}";
    many += "]}";
    add("run report of 150000 samples (each empty)", json_post("/v1/runs", many), 413,
        "\"field\":\"samples\"");
  }
  add("run report announcing 1 GiB",
      "POST /v1/runs HTTP/1.1\r\nHost: corpus\r\n" + key_header() +
          "Content-Type: application/json\r\nContent-Length: 1073741824\r\nConnection: "
          "close\r\n\r\n{",
      413, "Content-Length");
  add("run report with a sample at latitude 1e308",
      json_post("/v1/runs",
                R"({"format":"polmap-localization-run","version":1,"map_version":1,"pol":"full",)"
                R"("reference":"none","samples":[{"t_s":0,"lat_deg":1e308,"lon_deg":0,)"
                R"("yaw_enu_deg":0,"status":"tracking","cov_xx_m2":0,"cov_xy_m2":0,)"
                R"("cov_yy_m2":0,"cov_yaw_rad2":0},{}]})"),
      422, "samples[0].lat_deg");
  add("run id 10^20", get_request("/v1/runs/100000000000000000000", key_header()), 400, "run_id");
  // Map diffs (public reads: every parameter checked before two maps are read).
  add("diff from 10^20", get_request("/v1/maps/current/diff?from=100000000000000000000"), 400,
      "\"field\":\"from\"");
  add("diff from %00", get_request("/v1/maps/current/diff?from=1%00"), 400, "\"field\":\"from\"");
  add("diff of version -1", get_request("/v1/maps/-1/diff?from=1"), 400, "\"field\":\"version\"");
  add("diff from an unknown version", get_request("/v1/maps/current/diff?from=999999"), 404,
      "\"field\":\"from\"");
  add("diff bbox of NaN", get_request("/v1/maps/current/diff?from=current&bbox=nan,nan,nan,nan"),
      400, "\"field\":\"bbox\"");
  add("diff format with markup",
      get_request("/v1/maps/current/diff?from=current&format=%3Cscript%3E"), 400,
      "\"field\":\"format\"");
  // Resumable uploads (refused before any session or file exists).
  auto upload_open = [](const std::string& length_header) {
    return "POST /v1/uploads HTTP/1.1\r\nHost: corpus\r\n" + key_header() + length_header +
           "Content-Length: 0\r\nConnection: close\r\n\r\n";
  };
  add("upload session of 10^30 bytes",
      upload_open("Upload-Length: 1000000000000000000000000000000\r\n"), 400, "Upload-Length");
  add("upload session of -1 bytes", upload_open("Upload-Length: -1\r\n"), 400, "Upload-Length");
  add("upload session of 1 TB", upload_open("Upload-Length: 1000000000000\r\n"), 413,
      "Upload-Length");
  add("upload session with a short digest",
      upload_open("Upload-Length: 100\r\nUpload-Sha256: abc\r\n"), 400, "Upload-Sha256");
  add("chunk for a session id with a path",
      "PATCH /v1/uploads/..%2F..%2Fetc HTTP/1.1\r\nHost: corpus\r\n" + key_header() +
          "Upload-Offset: 0\r\nContent-Type: application/offset+octet-stream\r\n"
          "Content-Length: 4\r\nConnection: close\r\n\r\nabcd",
      404, "");  // decoded, the id has slashes: no route matches
  add("chunk for an unknown session",
      "PATCH /v1/uploads/0123456789abcdef0123456789abcdef HTTP/1.1\r\nHost: corpus\r\n" +
          key_header() +
          "Upload-Offset: 0\r\nContent-Type: application/offset+octet-stream\r\n"
          "Content-Length: 4\r\nConnection: close\r\n\r\nabcd",
      404, "upload_id");
  return rows;
}

class MaliciousCorpusTest : public ServerFixture {
 protected:
  void SetUp() override {
    ServerFixture::SetUp();
    auto c = client();
    for (int i = 0; i < 3; ++i) {
      const std::string id = "scene_drive_" + std::to_string(i);
      auto r = c.Post("/v1/drives", auth(), scene_tar(id, 11 + i), "application/x-tar");
      ASSERT_TRUE(r);
      ASSERT_EQ(r->status, 201) << r->body;
    }
    auto r = c.Post("/v1/maps", auth(), "{}", "application/json");
    ASSERT_EQ(r->status, 202) << r->body;
    server_->wait_for_builds();
    ASSERT_TRUE(store_->current_map_version());
    // A tile that exists, for the range rows.
    tile_ = store_->list_tiles(*store_->current_map_version(), TileLayer::Localization).at(0).key;
    ASSERT_EQ(c.Get("/v1/tiles/" + tiles::to_string(tile_))->status, 200);
  }

  struct Outcome {
    std::size_t rows = 0;
    double slowest_s = 0.0;
    std::string slowest;
  };

  /// Sends every row and checks the status, the time, the server's health, the store and
  /// the upload directory after it.
  Outcome run(const std::vector<Row>& rows) {
    Outcome o;
    const std::string before = store_digest(*store_);
    for (const Row& row : rows) {
      SCOPED_TRACE(row.name);
      const RawReply r = raw_request(port_, row.request, 3 * kAnswerBoundS);
      EXPECT_EQ(r.status, row.expected) << r.bytes.substr(0, 600);
      EXPECT_LT(r.seconds, kAnswerBoundS) << (r.timed_out ? "timed out" : "");
      EXPECT_LT(r.bytes.size(), 4096u) << "a refusal does not echo the request";
      if (!row.reply_has.empty()) {
        EXPECT_NE(r.bytes.find(row.reply_has), std::string::npos) << r.bytes.substr(0, 600);
      }
      const RawReply health = raw_request(port_, get_request("/health"), kAnswerBoundS);
      EXPECT_EQ(health.status, 200) << "the server must survive " << row.name;
      EXPECT_TRUE(store_digest(*store_) == before) << "the store changed:\n"
                                                   << store_digest(*store_);
      EXPECT_EQ(directory_entries(dir_ / "uploads"), 0u) << "upload leftovers";
      ++o.rows;
      if (r.seconds > o.slowest_s) {
        o.slowest_s = r.seconds;
        o.slowest = row.name;
      }
    }
    return o;
  }

  /// Refusals were logged on one line each, escaped: the control characters of a path or a
  /// member name never reach the log raw.
  void expect_log_escaped() {
    std::size_t lines = 0;
    for (const auto& l : log_lines()) {
      EXPECT_EQ(l.find_first_of(std::string("\x01\x1b\x7f\r\n", 5)), std::string::npos) << l;
      EXPECT_LE(l.size(), 5000u);  // messages quoting the request are cut
      lines += l.find("upload rejected") != std::string::npos;
    }
    EXPECT_GT(lines, 0u);
  }

  tiles::TileKey tile_{};
};

TEST_F(MaliciousCorpusTest, EveryRowGetsItsDocumentedStatusAndChangesNothing) {
  std::vector<Row> rows = package_rows();
  for (Row& r : request_rows(tile_)) rows.push_back(std::move(r));
  ASSERT_GE(rows.size(), 80u);

  // Twice: the first pass also warms up what the server keeps for good (a PROJ context and
  // SQLite connection per worker thread, GDAL's drivers, each worker's malloc arena); the
  // second must leave no more allocated memory behind than it found.
  const std::size_t rss_0 = resident_bytes();
  const Outcome first = run(rows);
  expect_log_escaped();
  {
    std::lock_guard lock(log_mutex_);  // the test's own copy of the log does not count
    log_.clear();
    log_.shrink_to_fit();
  }
  const std::size_t rss_1 = resident_bytes();
  const std::size_t heap_1 = live_heap_bytes();
  const Outcome second = run(rows);
  const std::size_t rss_2 = resident_bytes();
  const std::size_t heap_2 = live_heap_bytes();
  const auto mib = [](std::size_t b) { return static_cast<double>(b) / (1u << 20); };
  const Outcome& slow = first.slowest_s > second.slowest_s ? first : second;
  std::printf(
      "[corpus] %zu rows, twice; slowest answer %.3f s (%s); VmRSS %.1f -> %.1f -> %.1f MiB; "
      "allocated over the second pass %+.2f MiB\n",
      first.rows, slow.slowest_s, slow.slowest.c_str(), mib(rss_0), mib(rss_1), mib(rss_2),
      mib(heap_2) - mib(heap_1));
  EXPECT_LT(rss_1, rss_0 + kRssBoundBytes);
  EXPECT_LT(rss_2, rss_0 + kRssBoundBytes);
  EXPECT_LT(heap_2, heap_1 + kHeapRepeatBoundBytes);

  expect_log_escaped();
  // Still serving the map.
  auto c = client();
  EXPECT_EQ(c.Get("/v1/tiles/" + tiles::to_string(tile_))->status, 200);
}

using ZigZagTest = ServerFixture;

TEST_F(ZigZagTest, A100kSampleZigZagTrajectoryIsDrawnInBoundedTime) {
  // A valid package whose trajectory zig-zags 2..4 m to either side of its course every
  // sample (at most 80 m/s, plausible): the store keeps all 100000 samples (each is more than 1 m
  // from the last), and Douglas-Peucker's worst case is a zig-zag. Accepted, and the
  // trajectories layer of a vector tile on it is drawn within the bound.
  constexpr int kSamples = 100'000;
  SyntheticDrive d = make_synthetic_drive("zigzag", PolLevel::Full, 300, 280, 5, 10, 2, kSamples);
  const tiles::LocalFrame frame(d.pkg.manifest.origin);
  for (int i = 0; i < kSamples; ++i) {
    // Amplitude shrinking from 4 m to 2 m: from every split point on, the farthest vertex
    // from the chord is the next one (a regular zig-zag leaves the choice to rounding).
    const double amplitude = 2.0 + 2.0 * (kSamples - i) / kSamples;
    const GeoPoint g =
        frame.to_geo(Eigen::Vector2d{-8.0 + 0.3 * i, 12.0 + (i % 2 == 0 ? amplitude : -amplitude)});
    d.pkg.trajectory[i].lat_deg = g.lat_deg;
    d.pkg.trajectory[i].lon_deg = g.lon_deg;
  }
  d.pkg.manifest.distance_m = 4.0 * kSamples;
  const util::ScopedTempDir tmp(polmap::test::unique_test_dir("zigzag"));
  write_drive_package(d.pkg, d.raster, tmp.path() / "zigzag");
  const std::string tar = pack_drive_package(tmp.path() / "zigzag");

  RawReply r = raw_request(port_, upload_request(tar), 60.0);
  ASSERT_EQ(r.status, 201) << r.bytes.substr(0, 600);
  EXPECT_LT(r.seconds, kAnswerBoundS);
  ASSERT_EQ(store_->drive_trajectory("zigzag").size(), static_cast<std::size_t>(kSamples));

  // A z18 tile on the zig-zag, with a key that may see trajectories.
  const GeoPoint g = frame.to_geo(Eigen::Vector2d{-8.0 + 0.3 * 5000, 12.0});
  const tiles::TileKey k = tiles::tile_at(g.lat_deg, g.lon_deg, 18);
  r = raw_request(port_, get_request("/v1/mvt/" + tiles::to_string(k) + ".mvt", key_header()),
                  60.0);
  EXPECT_EQ(r.status, 200) << r.bytes.substr(0, 600);
  std::printf("[corpus] zig-zag of %d samples: vector tile in %.3f s\n", kSamples, r.seconds);
  EXPECT_LT(r.seconds, kAnswerBoundS);
  EXPECT_EQ(raw_request(port_, get_request("/health")).status, 200);
}

TEST(MaliciousCorpus, TheBasePackageIsValidSoEachRowTestsItsMutation) {
  const auto pkg = try_validate_package_bytes(base_tar());
  ASSERT_TRUE(pkg) << pkg.error().what();
  EXPECT_EQ(pkg->manifest.drive_id, "corpus_base");
  // The surgery helpers change nothing by themselves.
  EXPECT_EQ(edit_header(base_tar(), 1, [](char*) {}), base_tar());
  EXPECT_TRUE(try_validate_package_bytes(
      with_member(base_tar(), "candidates.gpkg", data_of(base_tar(), "candidates.gpkg"))));
  EXPECT_TRUE(try_validate_package_bytes(with_manifest(base_tar(), [](json&) {})));
}

}  // namespace
}  // namespace polmap::mapping::testing
