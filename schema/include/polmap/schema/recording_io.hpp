#pragma once
/// @file recording_io.hpp
/// Streaming, checksummed reader and writer of the recording format
/// (schema/recording.md). Neither ever holds more than one record in memory.
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>

#include "polmap/schema/recording.hpp"

namespace polmap {

/// Writes a recording record by record. Throws IoError on write failures.
class RecordingWriter {
 public:
  RecordingWriter(const std::filesystem::path& path, const RecordingHeader& header);
  ~RecordingWriter();
  RecordingWriter(const RecordingWriter&) = delete;
  RecordingWriter& operator=(const RecordingWriter&) = delete;

  void write(const TrajectorySample& sample);
  void write(const SensorFrame& frame);
  /// Writes the end-of-stream record and flushes; called by the destructor too.
  void close();
  [[nodiscard]] std::uint64_t bytes_written() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Reads a recording record by record. Every failure (truncation, checksum
/// mismatch, unknown version) throws FormatError naming the file and offset.
class RecordingReader final : public RecordSource {
 public:
  explicit RecordingReader(const std::filesystem::path& path);
  ~RecordingReader() override;
  [[nodiscard]] const RecordingHeader& header() const override;
  std::optional<RecordingRecord> next() override;
  /// Byte offset of the next record.
  [[nodiscard]] std::uint64_t offset() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace polmap
