#include "polmap/hdmap/lanelet2_osm.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <string>

#include "polmap/schema/errors.hpp"
#include "test_dir.hpp"

namespace polmap::hdmap {
namespace {

TEST(Lanelet2Osm, ReadsNodesWaysRelationsAndTags) {
  const util::ScopedTempDir dir(polmap::test::unique_test_dir("lanelet2"));
  const auto path = dir.path() / "m.osm";
  std::ofstream(path) << R"(<?xml version="1.0"?>
<osm version="0.6">
  <node id="1" lat="35.5" lon="139.25"><tag k="ele" v="12.5"/></node>
  <node id="2" lat="35.6" lon="139.3"><tag k="type" v="pole"/></node>
  <way id="10"><nd ref="1"/><nd ref="2"/><nd ref="99"/><tag k="type" v="curbstone"/>
    <tag k="subtype" v="high"/></way>
  <relation id="20"><member type="way" ref="10" role="left"/><tag k="type" v="lanelet"/>
    <tag k="subtype" v="road"/></relation>
</osm>)";
  const Lanelet2Osm m = read_lanelet2_osm_file(path);
  ASSERT_EQ(m.nodes.size(), 2U);
  EXPECT_DOUBLE_EQ(m.nodes[0].position.lat_deg, 35.5);
  EXPECT_DOUBLE_EQ(m.nodes[0].position.lon_deg, 139.25);
  EXPECT_DOUBLE_EQ(m.nodes[0].ele_m, 12.5);
  EXPECT_DOUBLE_EQ(m.nodes[0].position.alt_m, 0.0);
  EXPECT_EQ(m.nodes[1].type, "pole");
  ASSERT_NE(m.node(2), nullptr);
  EXPECT_EQ(m.node(99), nullptr);
  ASSERT_EQ(m.ways.size(), 1U);
  EXPECT_EQ(m.ways[0].node_refs, (std::vector<std::int64_t>{1, 2, 99}));  // unknown refs kept
  EXPECT_EQ(m.ways[0].type, "curbstone");
  EXPECT_EQ(m.ways[0].subtype, "high");
  ASSERT_EQ(m.relations.size(), 1U);
  EXPECT_EQ(m.relations[0].type, "lanelet");
  ASSERT_EQ(m.relations[0].members.size(), 1U);
  EXPECT_EQ(m.relations[0].members[0].role, "left");
  EXPECT_EQ(m.relations[0].members[0].ref, 10);
}

TEST(Lanelet2Osm, ErrorsNameTheFileAndTheElement) {
  const util::ScopedTempDir dir(polmap::test::unique_test_dir("lanelet2"));
  EXPECT_THROW((void)read_lanelet2_osm_file(dir.path() / "missing.osm"), IoError);
  const auto check = [&](const std::string& xml, const std::string& needle) {
    const auto path = dir.path() / "bad.osm";
    std::ofstream(path) << xml;
    try {
      (void)read_lanelet2_osm_file(path);
      ADD_FAILURE() << xml;
    } catch (const FormatError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find("bad.osm"), std::string::npos) << what;
      EXPECT_NE(what.find(needle), std::string::npos) << what;
    }
  };
  check("<osm><node id='1' lat='1' lon='2'></osm", "not valid XML");
  check("<map/>", "no <osm> root");
  check("<osm><node id='7' lat='x' lon='2'/></osm>", "node 7");
  check("<osm><node id='8' lat='91' lon='2'/></osm>", "node 8");
  check("<osm><node id='9' lon='2'/></osm>", "node 9");
}

}  // namespace
}  // namespace polmap::hdmap
