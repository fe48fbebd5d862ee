// Resumable uploads (POST /v1/uploads, PATCH/HEAD/DELETE /v1/uploads/{id}) against the real
// server on loopback: chunks appended at the acknowledged offset only, limits before the
// body, the per-key quota, sessions private to their key, expiry, a connection cut in the
// middle of a chunk, and the whole package validated by the path of POST /v1/drives before
// anything is stored.
#include <sqlite3.h>
#include <sys/socket.h>

#include <nlohmann/json.hpp>

#include "mapping_service/server/net_helpers.hpp"
#include "mapping_service/server_fixture.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/util/sha256.hpp"

namespace polmap::mapping::testing {
namespace {

using nlohmann::json;
constexpr const char* kChunkType = "application/offset+octet-stream";

/// Sends raw bytes on a new connection and returns the status of the reply (0: none).
int raw_status(int port, const std::string& bytes) {
  const int fd = connect_loopback(port);
  if (fd < 0) return 0;
  (void)::send(fd, bytes.data(), bytes.size(), MSG_NOSIGNAL);
  timeval tv{10, 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  char buf[512];
  const ssize_t r = ::recv(fd, buf, sizeof buf, 0);
  ::close(fd);
  return r > 12 ? std::atoi(std::string(buf + 9, 3).c_str()) : 0;
}

class ResumableUploadTest : public ServerFixture {
 protected:
  /// POST /v1/uploads for `tar`; returns the session path ("/v1/uploads/<id>").
  std::string create(const std::string& tar, const std::string& key = kKey, bool with_sha = true) {
    auto h = auth(key);
    h.emplace("Upload-Length", std::to_string(tar.size()));
    if (with_sha) h.emplace("Upload-Sha256", util::sha256_hex(tar));
    auto r = client().Post("/v1/uploads", h, "", "application/json");
    EXPECT_TRUE(r);
    if (!r) return {};
    EXPECT_EQ(r->status, 201) << r->body;
    EXPECT_EQ(r->get_header_value("Upload-Offset"), "0");
    EXPECT_EQ(r->get_header_value("Upload-Length"), std::to_string(tar.size()));
    return r->get_header_value("Location");
  }
  httplib::Result patch(const std::string& path, std::uint64_t offset, std::string_view bytes,
                        const std::string& key = kKey) {
    auto h = auth(key);
    h.emplace("Upload-Offset", std::to_string(offset));
    return client().Patch(path, h, bytes.data(), bytes.size(), kChunkType);
  }
  httplib::Result head(const std::string& path, const std::string& key = kKey) {
    return client().Head(path, auth(key));
  }
  /// Sends `tar` in chunks of `chunk` bytes; returns the answer to the last one.
  httplib::Result send_all(const std::string& path, const std::string& tar, std::size_t chunk) {
    std::size_t off = 0;
    for (;;) {
      const std::size_t n = std::min(chunk, tar.size() - off);
      auto r = patch(path, off, std::string_view(tar).substr(off, n));
      off += n;
      if (off == tar.size() || !r || r->status != 204) return r;
    }
  }
  std::size_t session_files() const {
    std::size_t n = 0;
    for ([[maybe_unused]] const auto& e :
         std::filesystem::directory_iterator(store_->upload_session_dir())) {
      ++n;
    }
    return n;
  }
  static std::string id_of(const std::string& path) { return path.substr(path.rfind('/') + 1); }
};

TEST_F(ResumableUploadTest, ChunksAtTheOffsetThenTheWholePackageIsStoredOnce) {
  const std::string& tar = scene_tar("scene_drive_0", 11);
  const std::string path = create(tar);
  ASSERT_TRUE(path.starts_with("/v1/uploads/")) << path;
  const std::string id = id_of(path);
  EXPECT_EQ(id.size(), 32U);
  const std::size_t chunk = tar.size() / 3 + 1;

  std::size_t off = 0;
  for (int i = 0; i < 2; ++i) {
    auto r = patch(path, off, std::string_view(tar).substr(off, chunk));
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 204) << r->body;
    off += chunk;
    EXPECT_EQ(r->get_header_value("Upload-Offset"), std::to_string(off));
    // Acknowledged bytes are in the session file; nothing is stored before the last byte.
    EXPECT_EQ(std::filesystem::file_size(store_->get_upload_session(id)->file), off);
    EXPECT_TRUE(store_->list_drives().empty());
    auto h = head(path);
    ASSERT_TRUE(h);
    EXPECT_EQ(h->status, 200);
    EXPECT_EQ(h->get_header_value("Upload-Offset"), std::to_string(off));
    EXPECT_EQ(h->get_header_value("Upload-Length"), std::to_string(tar.size()));
    EXPECT_FALSE(h->get_header_value("Upload-Expires").empty());
  }
  auto status = client().Get(path, auth());
  EXPECT_EQ(json::parse(status->body)["offset_bytes"], off);

  auto r = patch(path, off, std::string_view(tar).substr(off));
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 201) << r->body;
  const json j = json::parse(r->body);
  EXPECT_EQ(j["drive_id"], "scene_drive_0");
  EXPECT_EQ(j["status"], "inserted");
  EXPECT_EQ(j["content_hash"], util::sha256_hex(tar));
  EXPECT_EQ(r->get_header_value("Location"), "/v1/drives/scene_drive_0");
  // The stored members are the package's, byte for byte; the session is over.
  const auto d = store_->get_drive("scene_drive_0");
  ASSERT_TRUE(d);
  for (const auto& m : read_ustar(tar)) {
    EXPECT_EQ(util::read_file_bytes(d->package_path / m.name), m.data) << m.name;
  }
  // The session is complete: its bytes are gone, its answer stays until it expires.
  auto done = head(path);
  ASSERT_TRUE(done);
  EXPECT_EQ(done->status, 200);
  EXPECT_EQ(done->get_header_value("Upload-Offset"), std::to_string(tar.size()));
  EXPECT_EQ(done->get_header_value("Upload-Complete"), "201");
  ASSERT_TRUE(store_->get_upload_session(id)->outcome);
  EXPECT_EQ(session_files(), 0U);
  EXPECT_EQ(upload_leftovers(), 0U);

  // The same bytes again, resumably: already present, as with POST /v1/drives.
  const std::string again = create(tar);
  r = send_all(again, tar, tar.size());
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(json::parse(r->body)["status"], "already_present");
  EXPECT_EQ(store_->list_drives().size(), 1U);
  EXPECT_EQ(session_files(), 0U);
}

TEST_F(ResumableUploadTest, ACompletedSessionRepeatsItsAnswerUntilItExpires) {
  const std::string& tar = scene_tar("scene_drive_2", 13);
  const std::string path = create(tar);
  const std::size_t chunk = tar.size() / 2 + 1;
  auto first = send_all(path, tar, chunk);
  ASSERT_TRUE(first);
  ASSERT_EQ(first->status, 201) << first->body;
  // Say that answer was lost on the way. The client resends its last chunk: the session
  // refuses more bytes and names its end ...
  auto resent = patch(path, chunk, std::string_view(tar).substr(chunk));
  ASSERT_TRUE(resent);
  EXPECT_EQ(resent->status, 409) << resent->body;
  EXPECT_EQ(resent->get_header_value("Upload-Offset"), std::to_string(tar.size()));
  EXPECT_EQ(resent->get_header_value("Upload-Complete"), "201");
  // ... where an empty PATCH gets the same answer, byte for byte; nothing is stored twice.
  auto again = patch(path, tar.size(), "");
  ASSERT_TRUE(again);
  EXPECT_EQ(again->status, 201);
  EXPECT_EQ(again->body, first->body);
  EXPECT_EQ(again->get_header_value("Location"), "/v1/drives/scene_drive_2");
  EXPECT_EQ(store_->list_drives().size(), 1U);
  auto status = client().Get(path, auth());
  ASSERT_TRUE(status);
  const json j = json::parse(status->body);
  EXPECT_EQ(j["complete"], true);
  EXPECT_EQ(j["outcome"]["status"], 201);
  EXPECT_EQ(j["outcome"]["location"], "/v1/drives/scene_drive_2");
  EXPECT_EQ(j["outcome"]["response"]["drive_id"], "scene_drive_2");
  EXPECT_EQ(patch(path, tar.size(), "", kOtherKey)->status, 404);  // the owner's answer only
  // A completed session no longer counts against the key's quota of open sessions.
  for (int i = 0; i < 4; ++i) EXPECT_TRUE(create(tar).starts_with("/v1/uploads/")) << i;
  // Once it expires it is gone like any session.
  EXPECT_EQ(store_->sweep_expired_upload_sessions(std::chrono::system_clock::now() +
                                                  std::chrono::hours(48)),
            5U);
  EXPECT_EQ(head(path)->status, 404);
}

TEST_F(ResumableUploadTest, AChunkAtAnotherOffsetIsAConflictAndAppendsNothing) {
  const std::string& tar = scene_tar("scene_drive_0", 11);
  const std::string path = create(tar);
  const std::string id = id_of(path);
  auto r = patch(path, 5, std::string_view(tar).substr(5, 100));
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 409) << r->body;
  EXPECT_EQ(r->get_header_value("Upload-Offset"), "0");
  EXPECT_EQ(json::parse(r->body)["offset_bytes"], 0);
  EXPECT_EQ(json::parse(r->body)["field"], "Upload-Offset");

  ASSERT_EQ(patch(path, 0, std::string_view(tar).substr(0, 1000))->status, 204);
  // The same chunk again (a client that missed the answer): refused, not appended twice.
  r = patch(path, 0, std::string_view(tar).substr(0, 1000));
  EXPECT_EQ(r->status, 409);
  EXPECT_EQ(r->get_header_value("Upload-Offset"), "1000");
  EXPECT_EQ(store_->get_upload_session(id)->offset_bytes, 1000U);
  EXPECT_EQ(std::filesystem::file_size(store_->get_upload_session(id)->file), 1000U);
  // The rest from the right offset completes it.
  r = patch(path, 1000, std::string_view(tar).substr(1000));
  EXPECT_EQ(r->status, 201) << r->body;
}

TEST_F(ResumableUploadTest, LimitsApplyBeforeTheBody) {
  ServerConfig cfg;
  cfg.max_upload_bytes = 1 << 20;
  cfg.max_upload_chunk_bytes = 64 << 10;
  restart(cfg);
  auto c = client();
  auto h = auth();
  h.emplace("Upload-Length", std::to_string((1 << 20) + 1));
  auto r = c.Post("/v1/uploads", h, "", "application/json");
  EXPECT_EQ(r->status, 413) << r->body;
  EXPECT_EQ(json::parse(r->body)["field"], "Upload-Length");
  for (const char* bad : {"", "0", "-5", "12abc", "99999999999999999999999"}) {
    auto hb = auth();
    if (*bad != '\0') hb.emplace("Upload-Length", bad);
    r = c.Post("/v1/uploads", hb, "", "application/json");
    EXPECT_EQ(r->status, 400) << bad << ": " << r->body;
  }
  auto hs = auth();
  hs.emplace("Upload-Length", "100");
  hs.emplace("Upload-Sha256", "not-a-digest");
  EXPECT_EQ(c.Post("/v1/uploads", hs, "", "application/json")->status, 400);
  h = {{"Upload-Length", "100"}};
  EXPECT_EQ(c.Post("/v1/uploads", h, "", "application/json")->status, 401);

  const std::string tar(100000, 'x');
  const std::string path = create(tar, kKey, false);
  const std::string key = "Authorization: Bearer " + std::string(kKey) + "\r\n";
  const std::string patch_head = "PATCH " + path + " HTTP/1.1\r\nHost: x\r\n" + key +
                                 "Content-Type: " + kChunkType + "\r\nUpload-Offset: 0\r\n";
  // A chunk announced above the chunk limit: refused before a body byte is sent.
  EXPECT_EQ(raw_status(port_, patch_head + "Content-Length: 100000000\r\n\r\n"), 413);
  r = patch(path, 0, std::string_view(tar).substr(0, (64 << 10) + 1));
  EXPECT_EQ(r->status, 413) << r->body;
  EXPECT_EQ(raw_status(port_, "PATCH " + path + " HTTP/1.1\r\nHost: x\r\n" + key +
                                  "Content-Type: " + kChunkType +
                                  "\r\nUpload-Offset: 0\r\nTransfer-Encoding: chunked\r\n\r\n"),
            411);
  EXPECT_EQ(
      raw_status(port_, "PATCH " + path + " HTTP/1.1\r\nHost: x\r\nContent-Type: " + kChunkType +
                            "\r\nUpload-Offset: 0\r\nContent-Length: "
                            "100000000\r\n\r\n"),
      401);
  ASSERT_EQ(patch(path, 0, std::string_view(tar).substr(0, 60000))->status, 204);
  r = patch(path, 60000, std::string_view(tar).substr(0, 50000));  // ends beyond 100000
  EXPECT_EQ(r->status, 413) << r->body;
  r = client().Patch(path, auth(), tar.data(), 10, "application/octet-stream");
  EXPECT_EQ(r->status, 415) << r->body;
  auto ho = auth();
  ho.emplace("Upload-Offset", "sixty");
  EXPECT_EQ(client().Patch(path, ho, tar.data(), 10, kChunkType)->status, 400);
  EXPECT_EQ(store_->get_upload_session(id_of(path))->offset_bytes, 60000U);
  EXPECT_EQ(client().Get("/health")->status, 200);
}

TEST_F(ResumableUploadTest, EachKeyHasAQuotaOfSessionsAndBytes) {
  ServerConfig cfg;
  cfg.max_upload_sessions_per_key = 2;
  cfg.max_upload_session_bytes_per_key = 1000;
  restart(cfg);
  const std::string a = create(std::string(100, 'a'));
  (void)create(std::string(100, 'b'));
  auto h = auth();
  h.emplace("Upload-Length", "100");
  auto r = client().Post("/v1/uploads", h, "", "application/json");
  EXPECT_EQ(r->status, 429) << r->body;
  EXPECT_EQ(json::parse(r->body)["field"], "max_upload_sessions_per_key");
  EXPECT_EQ(json::parse(r->body)["limit"], 2);
  // Another key has its own quota, of bytes too.
  auto other = auth(kOtherKey);
  other.emplace("Upload-Length", "1001");
  r = client().Post("/v1/uploads", other, "", "application/json");
  EXPECT_EQ(r->status, 429) << r->body;
  EXPECT_EQ(json::parse(r->body)["field"], "max_upload_session_bytes_per_key");
  (void)create(std::string(1000, 'c'), kOtherKey);
  // An aborted session frees its place.
  EXPECT_EQ(client().Delete(a, auth())->status, 204);
  EXPECT_EQ(head(a)->status, 404);
  EXPECT_FALSE(create(std::string(100, 'd')).empty());
}

TEST_F(ResumableUploadTest, ASessionIsInvisibleToOtherKeys) {
  const std::string& tar = scene_tar("scene_drive_0", 11);
  const std::string path = create(tar);
  ASSERT_EQ(patch(path, 0, std::string_view(tar).substr(0, 500))->status, 204);
  EXPECT_EQ(head(path, kOtherKey)->status, 404);
  EXPECT_EQ(patch(path, 500, std::string_view(tar).substr(500, 500), kOtherKey)->status, 404);
  EXPECT_EQ(client().Delete(path, auth(kOtherKey))->status, 404);
  EXPECT_EQ(store_->get_upload_session(id_of(path))->offset_bytes, 500U);
  // Malformed or unknown ids: 404 as well.
  for (const std::string& bad : {std::string("xyz"), std::string(32, 'g'), std::string(33, 'a'),
                                 std::string(32, 'a'), id_of(path) + "0", std::string(32, 'A')}) {
    EXPECT_EQ(head("/v1/uploads/" + bad)->status, 404) << bad;
  }
  EXPECT_EQ(head(path)->status, 200);
}

TEST_F(ResumableUploadTest, AnExpiredSessionIsGoneAndSweptWithItsFile) {
  const std::string& tar = scene_tar("scene_drive_0", 11);
  const std::string path = create(tar);
  const std::string live = create(scene_tar("scene_drive_1", 12));
  ASSERT_EQ(patch(path, 0, std::string_view(tar).substr(0, 500))->status, 204);
  const auto file = store_->get_upload_session(id_of(path))->file;
  {  // Its expiry passes (as if a day went by).
    sqlite3* db = nullptr;
    ASSERT_EQ(sqlite3_open((dir_ / "map.db").c_str(), &db), SQLITE_OK);
    const std::string sql =
        "UPDATE upload_sessions SET expires_at = '2000-01-01T00:00:00Z' "
        "WHERE id = '" +
        id_of(path) + "'";
    EXPECT_EQ(sqlite3_exec(db, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK);
    sqlite3_close(db);
  }
  EXPECT_EQ(head(path)->status, 410);
  auto r = patch(path, 500, std::string_view(tar).substr(500, 500));
  EXPECT_EQ(r->status, 410) << r->body;
  // The next create sweeps it: row and file; the unexpired session stays.
  (void)create(std::string(10, 'x'));
  EXPECT_FALSE(store_->get_upload_session(id_of(path)));
  EXPECT_FALSE(std::filesystem::exists(file));
  EXPECT_EQ(head(path)->status, 404);
  EXPECT_EQ(head(live)->status, 200);
  EXPECT_TRUE(store_->list_drives().empty());
}

TEST_F(ResumableUploadTest, AChunkCutMidwayKeepsWhatArrivedAndTheUploadResumes) {
  const std::string& tar = scene_tar("scene_drive_0", 11);
  const std::string path = create(tar);
  const std::string id = id_of(path);
  ASSERT_GT(tar.size(), 200000U);
  // The client sends the head of a 150 kB chunk and 60 kB of it, then the link is lost.
  {
    const int fd = connect_loopback(port_);
    ASSERT_GE(fd, 0);
    const std::string head_bytes =
        "PATCH " + path + " HTTP/1.1\r\nHost: x\r\nAuthorization: " + "Bearer " + kKey +
        "\r\nContent-Type: " + kChunkType +
        "\r\nUpload-Offset: 0\r\nContent-Length: 150000\r\n\r\n" + tar.substr(0, 60000);
    ASSERT_EQ(::send(fd, head_bytes.data(), head_bytes.size(), MSG_NOSIGNAL),
              static_cast<ssize_t>(head_bytes.size()));
    ::close(fd);
  }
  // The bytes that arrived whole are durable and acknowledged; nothing is stored yet.
  ASSERT_TRUE([&] {
    for (int i = 0; i < 500; ++i) {
      if (store_->get_upload_session(id)->offset_bytes == 60000) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return false;
  }());
  auto h = head(path);
  EXPECT_EQ(h->get_header_value("Upload-Offset"), "60000");
  EXPECT_TRUE(store_->list_drives().empty());
  // A crash between writing a chunk and committing its offset leaves bytes beyond the
  // offset; the next chunk replaces them (the store's offset is the truth).
  {
    std::ofstream f(store_->get_upload_session(id)->file, std::ios::binary | std::ios::app);
    f << std::string(7000, '\xff');
  }
  auto r = patch(path, 60000, std::string_view(tar).substr(60000, 1000));
  ASSERT_EQ(r->status, 204) << r->body;
  EXPECT_EQ(std::filesystem::file_size(store_->get_upload_session(id)->file), 61000U);
  EXPECT_TRUE(store_->list_drives().empty());
  r = patch(path, 61000, std::string_view(tar).substr(61000));
  ASSERT_EQ(r->status, 201) << r->body;  // the declared SHA-256 matched: no stale byte
  EXPECT_EQ(store_->list_drives().size(), 1U);
  EXPECT_EQ(session_files(), 0U);
}

TEST_F(ResumableUploadTest, ACorruptPackageGetsTheAnswerOfPostDrivesAndNothingIsStored) {
  const std::string& good = scene_tar("scene_drive_1", 12);
  const std::vector<std::string> bad = {
      with_manifest_field(good, "pol_level", "quadruple"),  // 422 naming the field
      good.substr(0, good.size() / 2),                      // truncated archive: 400
      std::string(4000, 'x'),                               // not an archive: 400
  };
  for (const std::string& tar : bad) {
    auto direct = client().Post("/v1/drives", auth(), tar, "application/x-tar");
    ASSERT_TRUE(direct);
    ASSERT_GE(direct->status, 400);
    const std::string path = create(tar);
    auto r = send_all(path, tar, tar.size() / 2 + 1);
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, direct->status) << r->body;
    EXPECT_EQ(json::parse(r->body), json::parse(direct->body));
    // Refused for good: the upload is over, with that answer.
    EXPECT_EQ(head(path)->get_header_value("Upload-Complete"), std::to_string(direct->status));
  }
  // Bytes that are not what the session declared: 422, nothing stored.
  auto h = auth();
  h.emplace("Upload-Length", std::to_string(good.size()));
  h.emplace("Upload-Sha256", std::string(64, '0'));
  auto c = client().Post("/v1/uploads", h, "", "application/json");
  ASSERT_EQ(c->status, 201);
  auto r = send_all(c->get_header_value("Location"), good, good.size());
  EXPECT_EQ(r->status, 422) << r->body;
  EXPECT_EQ(json::parse(r->body)["field"], "Upload-Sha256");
  EXPECT_TRUE(store_->list_drives().empty());
  EXPECT_EQ(drive_store_entries(), 0U);
  EXPECT_EQ(session_files(), 0U);
  EXPECT_EQ(upload_leftovers(), 0U);
}

}  // namespace
}  // namespace polmap::mapping::testing
