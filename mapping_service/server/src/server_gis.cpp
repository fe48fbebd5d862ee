// GIS endpoints: GET /v1/export (GeoPackage / GeoJSON / Shapefile download) and the
// conversion of stored fleet gridmap tiles into PNG.
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "polmap/mapping_service/export.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/util/file.hpp"
#include "server_impl.hpp"

namespace polmap::mapping {

std::string gridmap_png(std::string_view payload) {
  static constexpr unsigned char kPngSignature[8] = {0x89, 'P', 'N', 'G', 0x0D, 0x0A, 0x1A, 0x0A};
  if (payload.size() >= 8 && std::memcmp(payload.data(), kPngSignature, 8) == 0) {
    return std::string(payload);
  }
  throw FormatError("stored gridmap tile is not a PNG");
}

std::string gridmap_overzoom_png(std::string_view ancestor_png, const tiles::TileKey& ancestor,
                                 const tiles::TileKey& key) {
  const int dz = key.z - ancestor.z;
  POLMAP_EXPECT(dz > 0 && dz <= 8);
  const cv::Mat buf(1, static_cast<int>(ancestor_png.size()), CV_8U,
                    const_cast<char*>(ancestor_png.data()));
  const cv::Mat img = cv::imdecode(buf, cv::IMREAD_UNCHANGED);
  if (img.empty()) throw FormatError("stored gridmap tile is not a decodable PNG");
  const int span = img.cols >> dz;  // source pixels covered by the child tile
  if (span < 1) throw ContractViolation("gridmap overzoom beyond the pixel size");
  const int ox = (key.x - (ancestor.x << dz)) * span;
  const int oy = (key.y - (ancestor.y << dz)) * span;
  cv::Mat out;
  cv::resize(img(cv::Rect(ox, oy, span, span)), out, img.size(), 0, 0, cv::INTER_NEAREST);
  std::vector<unsigned char> png;
  if (!cv::imencode(".png", out, png)) throw Error("PNG encoding failed");
  return {reinterpret_cast<const char*>(png.data()), png.size()};
}

namespace {

/// After a failed export: true if its scratch directory cannot take a 64 KiB write now,
/// i.e. the disk is full (GDAL's errors do not say why a write failed).
bool scratch_is_full(const std::filesystem::path& dir) {
  std::string templ = (dir / "polmap-export-probe-XXXXXX").string();
  const int fd = ::mkstemp(templ.data());
  if (fd < 0) return errno == ENOSPC || errno == EDQUOT;
  const std::string block(64u << 10, '\0');
  const int err = util::write_all(fd, block);  // a full disk may take part, then refuse
  ::close(fd);
  ::unlink(templ.c_str());
  return err == ENOSPC || err == EDQUOT;
}

}  // namespace

void Server::Impl::register_gis_routes() {
  http.Get("/v1/export", [this](const httplib::Request& req, httplib::Response& res) {
    if (!require(req, res, Access::Operate)) return;
    set_route("export");
    const std::string fmt = req.get_param_value("format");
    const auto format = parse_export_format(fmt);
    if (!format) {
      return reply_error(res, 400, "format must be gpkg, geojson, shp, gtiff or cog", "format");
    }
    std::optional<GeoBox> bbox;
    if (req.has_param("bbox")) {
      bbox = http::parse_bbox(req.get_param_value("bbox"));
      if (!bbox) {
        return reply_error(res, 400, "bbox must be minlon,minlat,maxlon,maxlat in degrees", "bbox");
      }
      if (bbox->crosses_antimeridian()) {
        return reply_error(res, 400, "bbox must not cross the antimeridian (min_lon <= max_lon)",
                           "bbox");
      }
    }
    bool is_explicit = false;
    const auto idx = resolve_version(req, res, is_explicit);
    if (!idx) return;
    const ConcurrencySlot slot(exports_in_flight, cfg.max_concurrent_exports);
    if (!slot.acquired()) {
      res.set_header("Retry-After", "30");
      return reply_error(res, 503,
                         std::to_string(cfg.max_concurrent_exports) +
                             " exports are being written already; retry later");
    }

    // Export into a private temp dir; the response streams the file and the releaser
    // removes the directory when the response is done (or the client went away).
    const std::filesystem::path scratch =
        cfg.upload_dir.empty() ? std::filesystem::temp_directory_path() : cfg.upload_dir;
    const std::string name =
        "polmap-map-v" + std::to_string(idx->version) + std::string(export_file_extension(*format));
    util::ScopedTempDir export_dir{std::filesystem::path()};
    ExportSummary summary;
    try {
      export_dir = util::ScopedTempDir::create(scratch, "polmap-export");
      summary = export_map(store, idx->version, *format, bbox, export_dir.path() / name);
    } catch (const IoError& e) {
      export_dir.remove();
      if (!scratch_is_full(scratch)) throw;
      log("warn", "export: storage full: " + std::string(e.what()));
      return reply_error(res, 507, kStorageFullMessage);
    }
    // Some GDAL writers (GeoJSON) do not notice a failed write: a file written while the
    // disk is full may be cut short. Not sent.
    if (scratch_is_full(scratch)) {
      export_dir.remove();
      log("warn", "export: storage full: " + name + " was written while the disk was full");
      return reply_error(res, 507, kStorageFullMessage);
    }
    const std::filesystem::path file = export_dir.path() / name;
    log("info", "export " + name + ": " + std::to_string(summary.points) + " points, " +
                    std::to_string(summary.lines) + " lines, " +
                    std::to_string(summary.gridmap_tiles) + " gridmap tiles");
    const auto size = std::filesystem::file_size(file);
    auto in = std::make_shared<std::ifstream>(file, std::ios::binary);
    if (!*in) throw IoError("cannot read the export " + file.string());
    res.status = 200;
    res.set_header("Content-Disposition", "attachment; filename=\"" + name + "\"");
    res.set_header("Cache-Control", is_explicit ? "public, max-age=3600" : "no-cache");
    res.set_content_provider(
        static_cast<size_t>(size), std::string(export_content_type(*format)),
        [in](size_t offset, size_t length, httplib::DataSink& sink) {
          std::vector<char> buf(std::min<size_t>(length, 1u << 16));
          in->seekg(static_cast<std::streamoff>(offset));
          in->read(buf.data(), static_cast<std::streamsize>(buf.size()));
          const auto got = static_cast<size_t>(in->gcount());
          if (got == 0) return false;
          return sink.write(buf.data(), got);
        },
        [owned = std::make_shared<util::ScopedTempDir>(std::move(export_dir)), in](bool) {
          in->close();
          owned->remove();
        });
  });
}

}  // namespace polmap::mapping
