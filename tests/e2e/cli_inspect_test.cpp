// CLI smoke test: the built `polmap inspect` on a good recording (exit 0, summary),
// a corrupted one (a flipped byte inside a record: exit 1, one error line naming
// the file) and a truncated one (exit 1, one line naming the file).
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "polmap/schema/recording_io.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/world.hpp"
#include "test_dir.hpp"

namespace polmap {
namespace {

const std::filesystem::path kPolmap = std::filesystem::path(POLMAP_BINARY_DIR) / "tools" / "polmap";

struct RunResult {
  int exit_code = -1;
  std::string output;  ///< stdout and stderr
  std::string stdout_text;
  std::string stderr_text;
};

/// Shell-quoted path (test paths contain no quotes). Built by appending: GCC 12
/// warns falsely (-Wrestrict) on `"'" + std::string`.
std::string quoted(const std::filesystem::path& p) {
  std::string q(1, '\'');
  q.append(p.string()).append(1, '\'');
  return q;
}

/// Runs the CLI with stdout and stderr captured separately.
RunResult run_polmap(const std::string& args, const std::filesystem::path& dir) {
  const auto err_file = dir / "stderr.txt";
  std::string cmd = quoted(kPolmap);
  cmd.append(1, ' ').append(args).append(" 2>").append(quoted(err_file));
  RunResult r;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (p == nullptr) return r;
  std::array<char, 4096> buf{};
  std::size_t n = 0;
  while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.output.append(buf.data(), n);
  const int status = ::pclose(p);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream f(err_file);
  std::stringstream ss;
  ss << f.rdbuf();
  r.stderr_text = ss.str();
  r.stdout_text = r.output;
  r.output += r.stderr_text;
  return r;
}

int count_lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n' ? 1 : 0;
  return n;
}

class CliInspect : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = polmap::test::unique_test_dir("e2e-inspect");
    // A short simulated drive (2 s: 60 sensor frames, 200 GNSS samples).
    sim::SimConfig cfg;
    cfg.seed = 5;
    cfg.duration_s = 2.0;
    auto world = sim::load_world("urban", 200.0, cfg.seed, cfg);
    sim::DriveSimulator simulator(world, cfg, 0);
    RecordingWriter w(good(), simulator.header());
    while (auto rec = simulator.next()) w.write(*rec);
    w.close();
  }
  static void TearDownTestSuite() { std::filesystem::remove_all(dir_); }
  static std::filesystem::path good() { return dir_ / "good.pmrec"; }

  static inline std::filesystem::path dir_;
};

TEST_F(CliInspect, BinaryExists) {
  ASSERT_TRUE(std::filesystem::exists(kPolmap)) << kPolmap << " (build the polmap target)";
}

TEST_F(CliInspect, GoodRecordingSummarizedWithExitZero) {
  const RunResult r = run_polmap("inspect " + quoted(good()), dir_);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("drive_0"), std::string::npos) << r.output;
  EXPECT_TRUE(r.stderr_text.empty() || r.stderr_text.find("error") == std::string::npos)
      << r.stderr_text;

  const RunResult j = run_polmap("inspect " + quoted(good()) + " --json", dir_);
  EXPECT_EQ(j.exit_code, 0) << j.output;
  const auto doc = nlohmann::json::parse(j.stdout_text);
  EXPECT_EQ(doc["valid"], true) << j.output;
  EXPECT_GE(doc["frames"].get<int>(), 57) << j.output;  // 2 s at 10 Hz x 3 sensors
  EXPECT_EQ(doc["drive_id"], "drive_0");
}

TEST_F(CliInspect, CorruptedRecordingFailsWithOneLineNamingTheFile) {
  const auto bad = dir_ / "corrupted.pmrec";
  std::filesystem::copy_file(good(), bad, std::filesystem::copy_options::overwrite_existing);
  {
    // Flip one byte in the middle of the file (inside a compressed frame record):
    // the record's CRC-32 no longer matches.
    std::fstream f(bad, std::ios::in | std::ios::out | std::ios::binary);
    const auto size = std::filesystem::file_size(bad);
    f.seekg(static_cast<std::streamoff>(size / 2));
    char c = 0;
    f.read(&c, 1);
    c = static_cast<char>(c ^ 0x5A);
    f.seekp(static_cast<std::streamoff>(size / 2));
    f.write(&c, 1);
  }
  const RunResult r = run_polmap("inspect " + quoted(bad), dir_);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_EQ(count_lines(r.stderr_text), 1) << r.stderr_text;
  EXPECT_EQ(r.stderr_text.rfind("polmap: error: ", 0), 0u) << r.stderr_text;
  EXPECT_NE(r.stderr_text.find(bad.string()), std::string::npos) << r.stderr_text;
  EXPECT_NE(r.stderr_text.find("byte"), std::string::npos) << r.stderr_text;
}

TEST_F(CliInspect, TruncatedRecordingFailsWithOneLineNamingTheFile) {
  const auto cut = dir_ / "truncated.pmrec";
  std::filesystem::copy_file(good(), cut, std::filesystem::copy_options::overwrite_existing);
  std::filesystem::resize_file(cut, std::filesystem::file_size(cut) * 2 / 3);
  const RunResult r = run_polmap("inspect " + quoted(cut), dir_);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_EQ(count_lines(r.stderr_text), 1) << r.stderr_text;
  EXPECT_NE(r.stderr_text.find(cut.string()), std::string::npos) << r.stderr_text;
}

TEST_F(CliInspect, MissingFileIsAnIoErrorNotACrash) {
  const RunResult r = run_polmap("inspect " + quoted(dir_ / "nope.pmrec"), dir_);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_EQ(count_lines(r.stderr_text), 1) << r.stderr_text;
  EXPECT_NE(r.stderr_text.find("nope.pmrec"), std::string::npos) << r.stderr_text;
}

}  // namespace
}  // namespace polmap
