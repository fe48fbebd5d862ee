#pragma once
/// @file recording_io.hpp
/// Streaming, checksummed reader and writer of the recording format
/// (schema/recording.md). Neither ever holds more than one record in memory.
///
/// What is lossless and what is quantized (details and error bounds in
/// schema/recording.md):
/// - header, trajectory samples, frame times, cycle indices, azimuth bin
///   centres, noise_sigma, range_bin_m: lossless;
/// - detections: range 1 mm, azimuth 1e-4 rad, radial velocity 1 mm/s,
///   SNR 0.01 dB (round to nearest);
/// - spectrum cells: per cell and channel block floating point, 8-bit I/Q
///   mantissas with a shared 8-bit exponent relative to noise_sigma
///   (|error| <= max(max(|I|,|Q|) / 127, noise_sigma / 512) per component);
/// - data cube: per range line block floating point, 16-bit mantissas
///   (|error| <= max |component| of the line / 32767).
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>

#include "polmap/schema/recording.hpp"

namespace polmap {

/// Detection quantization steps (round to nearest; |error| <= step / 2).
inline constexpr double kDetectionRangeStep_m = 1e-3;
inline constexpr double kDetectionAzimuthStep_rad = 1e-4;
inline constexpr double kDetectionVelocityStep_mps = 1e-3;
inline constexpr double kDetectionSnrStep_db = 0.01;

/// Spectrum sample quantization: mantissa m in [-127, 127] and exponent e in
/// [kSpectrumMinExponent, 127] shared by I and Q of one cell channel; the
/// decoded component is m * 2^e * noise_sigma.
inline constexpr int kSpectrumMantissaMax = 127;
inline constexpr int kSpectrumMinExponent = -8;

/// Upper bound of the uncompressed size of one record (guards allocations
/// against corrupt length fields; a full data cube of the paper's sensor is ~34 MB).
inline constexpr std::uint32_t kMaxRecordBytes = 1u << 30;

/// Options of RecordingWriter (defaults documented).
struct RecordingWriterOptions {
  /// zlib level of sensor-frame payloads, 0..9. Default 6 (zlib's default):
  /// level 9 saves ~1 % more and costs ~2x the time on spectrum payloads.
  int compression_level = 6;
};

/// Writes a recording record by record. Throws IoError on write failures and
/// ValidationError (naming the frame and field) on values the format cannot
/// represent: unsorted or out-of-range spectrum cells, non-finite detection
/// or spectrum values, a sensor id missing from the header, a cube while
/// header.has_cube is false, a cube whose data size mismatches its dimensions.
class RecordingWriter {
 public:
  RecordingWriter(const std::filesystem::path& path, const RecordingHeader& header);
  RecordingWriter(const std::filesystem::path& path, const RecordingHeader& header,
                  const RecordingWriterOptions& options);
  ~RecordingWriter();
  RecordingWriter(const RecordingWriter&) = delete;
  RecordingWriter& operator=(const RecordingWriter&) = delete;

  void write(const TrajectorySample& sample);
  void write(const SensorFrame& frame);
  /// Writes a record of either kind.
  void write(const RecordingRecord& record);
  /// Writes the end-of-stream record and flushes; called by the destructor too.
  void close();
  [[nodiscard]] std::uint64_t bytes_written() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Reads a recording record by record. Every failure (truncation, checksum
/// mismatch, unknown version) throws FormatError naming the file and offset.
/// A file that cannot be opened throws IoError.
class RecordingReader final : public RecordSource {
 public:
  explicit RecordingReader(const std::filesystem::path& path);
  ~RecordingReader() override;
  [[nodiscard]] const RecordingHeader& header() const override;
  std::optional<RecordingRecord> next() override;
  /// Byte offset of the next record.
  [[nodiscard]] std::uint64_t offset() const;
  /// Size of the file in bytes.
  [[nodiscard]] std::uint64_t file_size() const;
  /// Format version found in the file's preamble.
  [[nodiscard]] std::uint32_t file_format_version() const;
  /// True once next() has returned std::nullopt after a valid end record.
  [[nodiscard]] bool at_end() const;

 private:
  std::optional<RecordingRecord> next_record();
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace polmap
