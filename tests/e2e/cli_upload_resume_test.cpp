// `polmap upload` (the built executable) sends a package resumably through a loopback proxy
// that cuts its third chunk's connection in the middle: the CLI waits, asks HEAD for the
// offset, continues from there, and the drive is stored. From the bytes the proxy carried:
// the chunks' byte ranges never overlap (no byte before the last acknowledged offset goes
// twice) and cover the package exactly once.
#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <fstream>
#include <regex>

#include "mapping_service/server_fixture.hpp"
#include "polmap/util/sha256.hpp"
#include "support/tcp_proxy.hpp"

namespace polmap::mapping::testing {
namespace {

const std::filesystem::path kPolmap = std::filesystem::path(POLMAP_BINARY_DIR) / "tools" / "polmap";

/// One request the proxy carried and its answer.
struct Exchange {
  std::string method;
  std::optional<std::uint64_t> offset;  ///< request's Upload-Offset
  std::uint64_t body_bytes = 0;         ///< request body bytes that reached the server
  int status = 0;                       ///< 0: no answer (the cut connection)
  std::optional<std::uint64_t> acked;   ///< answer's Upload-Offset
};

std::optional<std::uint64_t> header_value(const std::string& head, const std::string& name) {
  std::smatch m;
  if (!std::regex_search(
          head, m, std::regex("\r\n" + name + ": ([0-9]+)\r\n", std::regex_constants::icase))) {
    return std::nullopt;
  }
  return std::stoull(m[1]);
}

Exchange parse(const test::TcpProxy::Record& r) {
  Exchange e;
  const std::size_t end = r.upstream.find("\r\n\r\n");
  const std::string head = r.upstream.substr(0, end == std::string::npos ? 0 : end + 2);
  e.method = r.upstream.substr(0, r.upstream.find(' '));
  e.offset = header_value(head, "Upload-Offset");
  if (end != std::string::npos) e.body_bytes = r.upstream.size() - end - 4;
  if (r.downstream.size() > 12) e.status = std::atoi(r.downstream.substr(9, 3).c_str());
  e.acked =
      header_value(r.downstream.substr(0, r.downstream.find("\r\n\r\n") + 2), "Upload-Offset");
  return e;
}

class CliUploadResume : public ServerFixture {
 protected:
  struct CliRun {
    int exit_code = -1;  ///< -1: did not exit normally
    std::string output;
  };
  /// Writes `tar` as a package file and runs `polmap upload` on it through `proxy` in 64 KiB
  /// chunks.
  CliRun upload_through(const test::TcpProxy& proxy, const std::string& tar,
                        const std::string& extra = "") const {
    const auto pkg = dir_ / "drive.tar";
    if (!std::filesystem::exists(pkg)) std::ofstream(pkg, std::ios::binary) << tar;
    const std::string cmd = kPolmap.string() +
                            " upload --server http://127.0.0.1:" + std::to_string(proxy.port()) +
                            " --package " + pkg.string() + " --api-key " + kKey +
                            " --chunk-mb 0.0625 --timeout-s 30 " + extra + " 2>&1";
    CliRun run;
    FILE* p = ::popen(cmd.c_str(), "r");
    if (p == nullptr) return run;
    std::array<char, 4096> buf{};
    std::size_t n = 0;
    while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) run.output.append(buf.data(), n);
    const int status = ::pclose(p);
    if (WIFEXITED(status)) run.exit_code = WEXITSTATUS(status);
    return run;
  }
  /// What the proxy carried, parsed, and how many connections it cut.
  static std::pair<std::vector<Exchange>, int> exchanges(const test::TcpProxy& proxy) {
    std::vector<Exchange> ex;
    int cut = 0;
    for (const auto& r : proxy.records()) {
      ex.push_back(parse(r));
      cut += r.cut ? 1 : 0;
    }
    return {ex, cut};
  }
};

TEST_F(CliUploadResume, ADroppedConnectionResumesWithoutResendingAcknowledgedBytes) {
  const std::string& tar = scene_tar("scene_drive_0", 11);
  const std::size_t chunk = 64u << 10;
  ASSERT_GT(tar.size(), 4 * chunk);  // at least five chunks: the third is cut
  test::TcpProxy::Options po;
  po.target_port = port_;
  po.cut_nth = 3;
  po.cut_after_bytes = 20000;  // the head and part of the third chunk's body
  test::TcpProxy proxy(po);
  ASSERT_GT(proxy.port(), 0);
  const CliRun run = upload_through(proxy, tar);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("drive scene_drive_0 uploaded"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("1 retries"), std::string::npos) << run.output;
  ASSERT_EQ(store_->list_drives().size(), 1U);
  EXPECT_EQ(store_->get_drive("scene_drive_0")->content_hash, util::sha256_hex(tar));

  const auto [ex, cut] = exchanges(proxy);
  EXPECT_EQ(cut, 1);
  ASSERT_GE(ex.size(), 3U);
  EXPECT_EQ(ex.front().method, "POST");
  EXPECT_EQ(ex.front().status, 201);
  // Every chunk starts at the last offset the server acknowledged (to a chunk or to HEAD):
  // the byte ranges follow each other without overlap or gap and end at the package's end.
  std::uint64_t acked = 0, covered = 0, sent = 0;
  int heads = 0;
  for (std::size_t i = 1; i < ex.size(); ++i) {
    const Exchange& e = ex[i];
    if (e.method == "HEAD") {
      ++heads;
      ASSERT_EQ(e.status, 200);
      ASSERT_TRUE(e.acked);
      EXPECT_EQ(*e.acked, covered) << "the server kept every byte that reached it";
      acked = *e.acked;
      continue;
    }
    ASSERT_EQ(e.method, "PATCH") << i;
    ASSERT_TRUE(e.offset) << i;
    EXPECT_EQ(*e.offset, acked) << "chunk " << i << " does not start at the acknowledged offset";
    EXPECT_EQ(*e.offset, covered) << "chunk " << i << " overlaps or leaves a gap";
    covered = *e.offset + e.body_bytes;
    sent += e.body_bytes;
    if (e.acked) acked = *e.acked;
  }
  EXPECT_EQ(heads, 1);
  EXPECT_EQ(covered, tar.size());
  EXPECT_EQ(sent, tar.size()) << "bytes sent twice: " << sent - tar.size();
  EXPECT_EQ(ex.back().status, 201);
  EXPECT_TRUE(std::filesystem::is_empty(store_->upload_session_dir()));
}

TEST_F(CliUploadResume, TheLostAnswerToTheLastChunkIsAskedForAgain) {
  // The last chunk arrives and the drive is stored, but the answer never reaches the CLI:
  // it asks HEAD where the session stands (complete, at its end) and gets the answer again
  // from an empty PATCH there, without sending a byte twice.
  const std::string& tar = scene_tar("scene_drive_0", 11);
  const std::size_t chunk = 64u << 10;
  test::TcpProxy::Options po;
  po.target_port = port_;
  po.cut_nth = static_cast<int>((tar.size() + chunk - 1) / chunk);  // the last chunk
  po.cut_before_answer = true;
  test::TcpProxy proxy(po);
  ASSERT_GT(proxy.port(), 0);
  const CliRun run = upload_through(proxy, tar);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("drive scene_drive_0 uploaded"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("the lost answer asked for again"), std::string::npos) << run.output;
  ASSERT_EQ(store_->list_drives().size(), 1U);

  const auto [ex, cut] = exchanges(proxy);
  EXPECT_EQ(cut, 1);
  ASSERT_GE(ex.size(), 3U);
  const Exchange& last = ex[ex.size() - 1];
  const Exchange& head = ex[ex.size() - 2];
  const Exchange& lost = ex[ex.size() - 3];
  EXPECT_EQ(lost.method, "PATCH");
  EXPECT_EQ(lost.status, 0);  // its answer never arrived
  EXPECT_EQ(head.method, "HEAD");
  EXPECT_EQ(head.acked, tar.size());
  EXPECT_EQ(last.method, "PATCH");
  EXPECT_EQ(last.offset, tar.size());
  EXPECT_EQ(last.body_bytes, 0U);
  EXPECT_EQ(last.status, 201);  // the answer the lost one had
  std::uint64_t sent = 0;
  for (const auto& e : ex) sent += e.method == "PATCH" ? e.body_bytes : 0;
  EXPECT_EQ(sent, tar.size()) << "bytes sent twice: " << sent - tar.size();
}

TEST_F(CliUploadResume, AnUploadThatGaveUpIsContinuedByTheNextRun) {
  // The first run gives up when the third chunk's connection is cut (--retries 0); the
  // session stays remembered beside the package, and the next run of the same command asks
  // HEAD where it stands and sends only the rest: over both runs every byte went once.
  const std::string& tar = scene_tar("scene_drive_0", 11);
  const auto state = dir_ / "drive.tar.upload-session";
  test::TcpProxy::Options po;
  po.target_port = port_;
  po.cut_nth = 3;
  po.cut_after_bytes = 20000;
  test::TcpProxy proxy(po);  // cuts its third connection only: the rerun goes through
  const CliRun gave_up = upload_through(proxy, tar, "--retries 0");
  ASSERT_NE(gave_up.exit_code, 0) << gave_up.output;
  EXPECT_NE(gave_up.output.find("the session is kept in"), std::string::npos) << gave_up.output;
  ASSERT_TRUE(std::filesystem::exists(state));
  EXPECT_TRUE(store_->list_drives().empty());
  const std::size_t first_run = proxy.records().size();

  const CliRun run = upload_through(proxy, tar);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("drive scene_drive_0 uploaded"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("continued the session of an earlier run"), std::string::npos)
      << run.output;
  EXPECT_FALSE(std::filesystem::exists(state));  // the upload ended: nothing to continue
  ASSERT_EQ(store_->list_drives().size(), 1U);
  EXPECT_EQ(store_->get_drive("scene_drive_0")->content_hash, util::sha256_hex(tar));

  const auto [ex, cut] = exchanges(proxy);
  EXPECT_EQ(cut, 1);
  ASSERT_GT(ex.size(), first_run);
  std::uint64_t sent = 0, kept = 0;
  for (std::size_t i = 0; i < first_run; ++i) {
    if (ex[i].method == "PATCH") {
      sent += ex[i].body_bytes;
      kept = *ex[i].offset + ex[i].body_bytes;  // the server keeps what reached it
    }
  }
  EXPECT_GT(kept, 0U);
  const Exchange& head = ex[first_run];
  EXPECT_EQ(head.method, "HEAD");  // the rerun asks where the session stands
  ASSERT_TRUE(head.acked);
  EXPECT_EQ(*head.acked, kept);
  for (std::size_t i = first_run; i < ex.size(); ++i) {
    if (ex[i].method == "POST") ADD_FAILURE() << "the rerun opened a new session";
    if (ex[i].method == "PATCH") sent += ex[i].body_bytes;
  }
  EXPECT_EQ(sent, tar.size()) << "bytes sent twice: " << sent - tar.size();

  // A state file that is not one is ignored (and replaced), not trusted.
  std::ofstream(state) << "{\"version\": 1, \"location\": \"/v1/drives\"}";
  const CliRun again = upload_through(proxy, tar);
  EXPECT_EQ(again.exit_code, 0) << again.output;
  EXPECT_NE(again.output.find("ignoring"), std::string::npos) << again.output;
  EXPECT_NE(again.output.find("already present"), std::string::npos) << again.output;
  EXPECT_FALSE(std::filesystem::exists(state));
}

TEST_F(CliUploadResume, SmallPackagesStillGoInOnePost) {
  const std::string& tar = scene_tar("scene_drive_1", 12);
  const auto pkg = dir_ / "drive.tar";
  std::ofstream(pkg, std::ios::binary) << tar;
  test::TcpProxy::Options po;
  po.target_port = port_;
  test::TcpProxy proxy(po);
  const std::string cmd = kPolmap.string() +
                          " upload --server http://127.0.0.1:" + std::to_string(proxy.port()) +
                          " --package " + pkg.string() + " --api-key " + kKey + " 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0);
  ASSERT_EQ(proxy.records().size(), 1U);
  EXPECT_TRUE(proxy.records()[0].upstream.starts_with("POST /v1/drives "));
  EXPECT_EQ(store_->list_drives().size(), 1U);
}

}  // namespace
}  // namespace polmap::mapping::testing
