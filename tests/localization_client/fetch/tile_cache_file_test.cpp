// The tile cache file (<cache_dir>/<z>/<x>/<y>.pmtc): exact round trips of every stored
// answer, files of the previous writer (no key/size lines), every truncation, corrupt
// headers and payloads, sizes that lie, the wrong key, and what the encoder refuses.
#include "polmap/localization_client/tile_cache_file.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "polmap/schema/errors.hpp"

namespace polmap::loc {
namespace {

using tiles::TileKey;
using S = TileCacheStatus;

const TileKey kKey{16, 34567, 22222};

tiles::LocalizationTile make_tile(const TileKey& key) {
  tiles::LocalizationTile t;
  t.key = key;
  t.map_version = 7;
  for (int i = 0; i < 5; ++i) {
    PointLandmark p;
    p.id = 100 + i;
    p.position_m = {1.5 * i, -2.0 * i};
    t.points.push_back(p);
  }
  LineLandmark l;
  l.id = 7;
  l.polyline_m = {{0.0, 0.0}, {10.0, 5.0}};
  t.lines.push_back(l);
  return t;
}

TileCacheRecord record_200(const TileKey& key = kKey) {
  TileCacheRecord r;
  r.http_status = 200;
  r.etag = "\"v7-1f3a 9\"";
  r.header_version = 7;
  r.fetched_unix_s = 1712345678.123456789;
  r.payload = tiles::encode_localization_tile(make_tile(key));
  return r;
}

void expect_same(const TileCacheRecord& a, const TileCacheRecord& b) {
  EXPECT_EQ(a.http_status, b.http_status);
  EXPECT_EQ(a.etag, b.etag);
  EXPECT_EQ(a.header_version, b.header_version);
  EXPECT_EQ(a.fetched_unix_s, b.fetched_unix_s);  // exact, not approximately
  EXPECT_EQ(a.payload, b.payload);
}

/// The header the previous writer produced: no key and size lines, fetch time with
/// std::to_string's six decimals.
std::string legacy_file(int status, const std::string& etag, const std::string& payload) {
  std::string s = "PMTC1\nstatus ";
  s += std::to_string(status);
  s += "\netag ";
  s += etag;
  s += "\nversion 7\nfetched 1712345678.250000\n\n";
  s += payload;
  return s;
}

/// `file` with the first header line starting with `name` replaced by `line`.
std::string with_line(std::string file, const std::string& name, const std::string& line) {
  const std::size_t at = file.find("\n" + name + " ");
  EXPECT_NE(at, std::string::npos) << name;
  const std::size_t end = file.find('\n', at + 1);
  file.replace(at + 1, end - at - 1, line);
  return file;
}

TEST(TileCacheFile, RoundTripOf200IsExact) {
  const TileCacheRecord rec = record_200();
  const std::string bytes = encode_tile_cache_file(rec, kKey);
  EXPECT_TRUE(bytes.starts_with("PMTC1\nstatus 200\n"));
  const TileCacheDecodeResult r = decode_tile_cache_file(bytes, kKey);
  ASSERT_TRUE(r.ok()) << r.message;
  EXPECT_TRUE(r.message.empty());
  expect_same(r.record, rec);
  EXPECT_EQ(r.tile.key, kKey);
  EXPECT_EQ(r.tile.map_version, 7u);
  EXPECT_EQ(r.tile.points.size(), 5u);
  EXPECT_EQ(r.tile.lines.size(), 1u);
  // Encoding the decoded record gives the same bytes.
  EXPECT_EQ(encode_tile_cache_file(r.record, kKey), bytes);
}

TEST(TileCacheFile, RoundTripOf204And404GivesAnEmptyTileOfTheKey) {
  for (const int status : {204, 404}) {
    TileCacheRecord rec;
    rec.http_status = status;
    rec.header_version = 12;
    rec.fetched_unix_s = 0.1;
    const TileCacheDecodeResult r = decode_tile_cache_file(encode_tile_cache_file(rec, kKey), kKey);
    ASSERT_TRUE(r.ok()) << status << ": " << r.message;
    expect_same(r.record, rec);
    EXPECT_EQ(r.tile.key, kKey);
    EXPECT_EQ(r.tile.map_version, 12u);
    EXPECT_TRUE(r.tile.points.empty());
    EXPECT_TRUE(r.tile.lines.empty());
  }
}

TEST(TileCacheFile, ReadsFilesOfThePreviousWriter) {
  const std::string payload = tiles::encode_localization_tile(make_tile(kKey));
  const TileCacheDecodeResult r = decode_tile_cache_file(legacy_file(200, "\"e\"", payload), kKey);
  ASSERT_TRUE(r.ok()) << r.message;
  EXPECT_EQ(r.record.etag, "\"e\"");
  EXPECT_EQ(r.record.fetched_unix_s, 1712345678.25);
  EXPECT_EQ(r.record.payload, payload);
  const TileCacheDecodeResult empty = decode_tile_cache_file(legacy_file(404, "", ""), kKey);
  ASSERT_TRUE(empty.ok()) << empty.message;
  EXPECT_EQ(empty.record.http_status, 404);
  EXPECT_EQ(empty.tile.key, kKey);
}

TEST(TileCacheFile, EveryTruncationIsDetected) {
  const std::string bytes = encode_tile_cache_file(record_200(), kKey);
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    const TileCacheDecodeResult r = decode_tile_cache_file(bytes.substr(0, n), kKey);
    EXPECT_EQ(r.status, S::Truncated) << "prefix of " << n << " bytes: " << r.message;
    EXPECT_FALSE(r.message.empty());
  }
}

TEST(TileCacheFile, SizeIsComparedWithTheBytesPresentNeverTrusted) {
  const std::string bytes = encode_tile_cache_file(record_200(), kKey);
  const std::string n = std::to_string(record_200().payload.size());
  EXPECT_EQ(
      decode_tile_cache_file(with_line(bytes, "size", "size 18446744073709551615"), kKey).status,
      S::Truncated);
  EXPECT_EQ(
      decode_tile_cache_file(with_line(bytes, "size", "size 99999999999999999999"), kKey).status,
      S::Malformed);  // does not fit 64 bits
  EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "size", "size -1"), kKey).status, S::Malformed);
  EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "size", "size 0x10"), kKey).status,
            S::Malformed);
  EXPECT_EQ(decode_tile_cache_file(bytes + "x", kKey).status, S::Malformed);  // trailing byte
  EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "size", "size " + n), kKey).status, S::Ok);
}

TEST(TileCacheFile, CorruptHeadersAreRejected) {
  const std::string bytes = encode_tile_cache_file(record_200(), kKey);
  EXPECT_EQ(decode_tile_cache_file("GIF89a\n\n", kKey).status, S::NotACacheFile);
  EXPECT_EQ(decode_tile_cache_file("PMTC2\n" + bytes.substr(6), kKey).status, S::NotACacheFile);
  EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "status", "status 500"), kKey).status,
            S::UnsupportedStatus);
  EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "status", "status 304"), kKey).status,
            S::UnsupportedStatus);
  for (const std::string bad : {"status", "status ", "status 2OO", "status +200"}) {
    EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "status", bad), kKey).status, S::Malformed)
        << bad;
  }
  for (const std::string bad :
       {"fetched nan", "fetched inf", "fetched -1", "fetched 1e400", "fetched 12abc", "fetched "}) {
    EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "fetched", bad), kKey).status, S::Malformed)
        << bad;
  }
  EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "version", "version 1.5"), kKey).status,
            S::Malformed);
  EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "key", "key 16/34567"), kKey).status,
            S::Malformed);
  // A required line missing, or present twice.
  EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "etag", "x-unknown 1"), kKey).status,
            S::Malformed);
  EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "etag", "version 7"), kKey).status,
            S::Malformed);
  // Control characters (a CR would survive into the If-None-Match header).
  EXPECT_EQ(decode_tile_cache_file(with_line(bytes, "etag", "etag \"a\"\r"), kKey).status,
            S::Malformed);
  // An ETag longer than any the fetcher stores.
  EXPECT_EQ(
      decode_tile_cache_file(
          with_line(bytes, "etag", "etag " + std::string(kMaxTileCacheEtagBytes + 1, 'e')), kKey)
          .status,
      S::Malformed);
  // A header without its end in the first kMaxTileCacheHeaderBytes.
  EXPECT_EQ(decode_tile_cache_file(
                with_line(bytes, "etag", "etag \"e\"\nx-pad " + std::string(1100, 'p')), kKey)
                .status,
            S::Malformed);
  // Lines a newer writer may add are ignored.
  const TileCacheDecodeResult r =
      decode_tile_cache_file(with_line(bytes, "etag", "etag \"e\"\nx-newer yes"), kKey);
  EXPECT_EQ(r.status, S::Ok) << r.message;
  EXPECT_EQ(r.record.etag, "\"e\"");
}

TEST(TileCacheFile, CorruptPayloadsAreRejected) {
  TileCacheRecord rec = record_200();
  std::string bytes = encode_tile_cache_file(rec, kKey);
  bytes[bytes.size() - 10] ^= 0x5a;  // inside the tile: its CRC fails
  const TileCacheDecodeResult r = decode_tile_cache_file(bytes, kKey);
  EXPECT_EQ(r.status, S::BadPayload);
  EXPECT_FALSE(r.message.empty());
  rec.payload = "not a tile";
  EXPECT_EQ(decode_tile_cache_file(encode_tile_cache_file(rec, kKey), kKey).status, S::BadPayload);
  // A 204 with bytes after the header (only possible in a file written by someone else).
  EXPECT_EQ(decode_tile_cache_file(legacy_file(204, "", "xyz"), kKey).status, S::BadPayload);
}

TEST(TileCacheFile, WrongKeyIsRejected) {
  const TileKey other{16, 34567, 22223};
  // The key line names another tile.
  EXPECT_EQ(decode_tile_cache_file(encode_tile_cache_file(record_200(), kKey), other).status,
            S::WrongKey);
  TileCacheRecord empty;
  empty.http_status = 204;
  EXPECT_EQ(decode_tile_cache_file(encode_tile_cache_file(empty, kKey), other).status, S::WrongKey);
  // The payload is another tile (a file without a key line, or a lying one).
  const std::string payload = tiles::encode_localization_tile(make_tile(other));
  EXPECT_EQ(decode_tile_cache_file(legacy_file(200, "", payload), kKey).status, S::WrongKey);
  TileCacheRecord lying = record_200(other);
  EXPECT_EQ(decode_tile_cache_file(encode_tile_cache_file(lying, kKey), kKey).status, S::WrongKey);
}

TEST(TileCacheFile, PayloadOverTheLimitIsTooLarge) {
  const TileCacheRecord rec = record_200();
  const std::string bytes = encode_tile_cache_file(rec, kKey);
  EXPECT_EQ(decode_tile_cache_file(bytes, kKey, rec.payload.size() - 1).status, S::TooLarge);
  EXPECT_EQ(decode_tile_cache_file(bytes, kKey, rec.payload.size()).status, S::Ok);
}

TEST(TileCacheFile, EncoderRefusesWhatNoReaderWouldAccept) {
  TileCacheRecord rec = record_200();
  rec.http_status = 500;
  EXPECT_THROW((void)encode_tile_cache_file(rec, kKey), ValidationError);
  rec = record_200();
  rec.etag = "\"a\"\n\nPMTC1";
  EXPECT_THROW((void)encode_tile_cache_file(rec, kKey), ValidationError);
  rec.etag = std::string(kMaxTileCacheEtagBytes + 1, 'e');
  EXPECT_THROW((void)encode_tile_cache_file(rec, kKey), ValidationError);
  rec.etag = std::string(kMaxTileCacheEtagBytes, 'e');
  EXPECT_NO_THROW((void)encode_tile_cache_file(rec, kKey));
  rec.fetched_unix_s = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW((void)encode_tile_cache_file(rec, kKey), ValidationError);
  rec.fetched_unix_s = -1.0;
  EXPECT_THROW((void)encode_tile_cache_file(rec, kKey), ValidationError);
  rec = record_200();
  EXPECT_THROW((void)encode_tile_cache_file(rec, TileKey{1, 5, 0}), ValidationError);
  rec.http_status = 404;  // with the 200's payload still set
  EXPECT_THROW((void)encode_tile_cache_file(rec, kKey), ValidationError);
}

TEST(TileCacheFile, StatusNames) {
  EXPECT_EQ(to_string(S::Ok), "ok");
  EXPECT_EQ(to_string(S::Truncated), "truncated");
  EXPECT_EQ(to_string(S::WrongKey), "wrong_key");
}

}  // namespace
}  // namespace polmap::loc
