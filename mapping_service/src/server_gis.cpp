// GIS endpoints: GET /v1/export (GeoPackage / GeoJSON / Shapefile download) and the
// conversion of stored fleet gridmap tiles into PNG.
#include <cstring>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "polmap/schema/errors.hpp"
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

void Server::Impl::register_gis_routes() {
  http.Get("/v1/export", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("export");
    const std::string format = req.get_param_value("format");
    if (format != "gpkg" && format != "geojson" && format != "shp") {
      return reply_error(res, 400, "format must be gpkg, geojson or shp", "format");
    }
    if (req.has_param("bbox") && !http::parse_bbox(req.get_param_value("bbox"))) {
      return reply_error(res, 400, "bbox must be minlon,minlat,maxlon,maxlat in degrees", "bbox");
    }
    bool is_explicit = false;
    const auto idx = resolve_version(req, res, is_explicit);
    if (!idx) return;
    reply_error(res, 501, "GIS export is not available in this build yet");
  });
}

}  // namespace polmap::mapping
