// candidates.gpkg of a drive package: the deterministic GeoPackage writer (GDAL).
#include <gdal_priv.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>

#include <cmath>

#include "candidates_schema.hpp"
#include "package_internal.hpp"
#include "polmap/schema/json.hpp"

namespace polmap::mapping::detail {

// ------------------------------------------------------------------------ candidates.gpkg

namespace {

OGRLayer* create_layer(GDALDataset& ds, const GpkgLayerSchema& schema, OGRSpatialReference& srs,
                       const std::string& path) {
  const std::string desc = std::string("DESCRIPTION=") + schema.description;
  const char* opts[] = {desc.c_str(), nullptr};
  OGRLayer* layer = ds.CreateLayer(schema.name, &srs, schema.geometry, const_cast<char**>(opts));
  if (layer == nullptr) throw IoError(path + ": cannot create layer " + schema.name);
  for (const auto& f : schema.fields) {
    OGRFieldDefn def(f.name, f.type);
    if (layer->CreateField(&def) != OGRERR_NONE) {
      throw IoError(path + ": cannot create field " + schema.name + "." + f.name);
    }
  }
  return layer;
}

void create_feature(OGRLayer* layer, OGRFeature& f, const std::string& path) {
  if (layer->CreateFeature(&f) != OGRERR_NONE) {
    throw IoError(path + ": cannot write a feature of layer " + layer->GetName());
  }
}

}  // namespace

void write_candidates_gpkg(const std::string& path, const tiles::LocalFrame& frame,
                           const std::vector<PointCandidate>& points,
                           const std::vector<LineCandidate>& lines,
                           const std::vector<TrajectorySample>& trajectory) {
  ensure_gdal();
  GdalErrorCapture capture;
  // Fixed gpkg_contents.last_change: the same candidates give the same bytes.
  ScopedGdalConfig fixed_date("OGR_CURRENT_DATE", "2000-01-01T00:00:00.000Z");
  ScopedGdalConfig no_pam("GDAL_PAM_ENABLED", "NO");
  GDALDriver* drv = GetGDALDriverManager()->GetDriverByName("GPKG");
  if (drv == nullptr) throw IoError("GDAL has no GPKG driver");
  GDALDatasetUniquePtr ds(drv->Create(path.c_str(), 0, 0, 0, GDT_Unknown, nullptr));
  if (!ds) throw IoError(path + ": cannot create GeoPackage: " + capture.last_message());
  OGRSpatialReference wgs84;
  wgs84.importFromEPSG(4326);
  wgs84.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);

  OGRLayer* lp = create_layer(*ds, kPointsLayer, wgs84, path);
  OGRLayer* ll = create_layer(*ds, kLinesLayer, wgs84, path);
  OGRLayer* lt = create_layer(*ds, kTrajectoryLayer, wgs84, path);

  if (ds->StartTransaction() != OGRERR_NONE) throw IoError(path + ": cannot start transaction");
  {
    OGRFeature f(lp->GetLayerDefn());
    for (const auto& p : points) {
      const GeoPoint g = frame.to_geo(p.position_m);
      f.SetFID(OGRNullFID);
      f.SetField("strength", p.strength);
      f.SetField("power_db", p.power_db);
      f.SetField("scattering", std::string(to_string(p.scattering)).c_str());
      f.SetField("num_cells", static_cast<GIntBig>(p.num_cells));
      f.SetField("x_m", p.position_m.x());
      f.SetField("y_m", p.position_m.y());
      OGRPoint pt(g.lon_deg, g.lat_deg);
      f.SetGeometry(&pt);
      create_feature(lp, f, path);
    }
  }
  {
    OGRFeature f(ll->GetLayerDefn());
    for (const auto& l : lines) {
      const GeoPoint a = frame.to_geo(l.start_m);
      const GeoPoint b = frame.to_geo(l.end_m);
      f.SetFID(OGRNullFID);
      f.SetField("strength", l.strength);
      f.SetField("x0_m", l.start_m.x());
      f.SetField("y0_m", l.start_m.y());
      f.SetField("x1_m", l.end_m.x());
      f.SetField("y1_m", l.end_m.y());
      f.SetField("length_m", (l.end_m - l.start_m).norm());
      OGRLineString ls;
      ls.addPoint(a.lon_deg, a.lat_deg);
      ls.addPoint(b.lon_deg, b.lat_deg);
      f.SetGeometry(&ls);
      create_feature(ll, f, path);
    }
  }
  {
    OGRFeature f(lt->GetLayerDefn());
    for (const auto& s : trajectory) {
      const Eigen::Vector2d xy = frame.to_local(s.lat_deg, s.lon_deg);
      f.SetFID(OGRNullFID);
      f.SetField("time_s", s.time_s);
      f.SetField("yaw_enu_rad", s.yaw_enu_rad);
      f.SetField("speed_mps", s.speed_mps);
      f.SetField("yaw_rate_rps", s.yaw_rate_rps);
      f.SetField("std_east_m", static_cast<double>(s.std_east_m));
      f.SetField("std_north_m", static_cast<double>(s.std_north_m));
      f.SetField("std_yaw_rad", static_cast<double>(s.std_yaw_rad));
      f.SetField("solution", std::string(to_string(s.solution)).c_str());
      f.SetField("x_m", xy.x());
      f.SetField("y_m", xy.y());
      OGRPoint pt(s.lon_deg, s.lat_deg);
      f.SetGeometry(&pt);
      create_feature(lt, f, path);
    }
  }
  if (ds->CommitTransaction() != OGRERR_NONE) {
    throw IoError(path + ": cannot commit: " + capture.last_message());
  }
  GDALDataset* raw = ds.release();
  CPLErrorReset();
  GDALClose(raw);
  if (CPLGetLastErrorType() >= CE_Failure) {
    throw IoError(path + ": cannot finish GeoPackage: " + capture.last_message());
  }
}

}  // namespace polmap::mapping::detail
