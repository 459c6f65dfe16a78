// CRC-32C (Castagnoli polynomial 0x1EDC6F41, reflected 0x82F63B78), the checksum of the
// database file's sections: SSE4.2's crc32 instruction when the CPU has it (8 bytes per
// instruction, three interleaved streams), else a slice-by-8 table. Both give the same
// value; CRC-32C("123456789") = 0xE3069283.
#pragma once

#include <cstddef>
#include <cstdint>

namespace sope {

// CRC-32C of `size` bytes at `data`, continuing from `crc` (the value returned for the
// preceding bytes; 0 to start).
uint32_t Crc32c(const void* data, size_t size, uint32_t crc = 0);

namespace internal {
// The portable table implementation (exposed for tests against the hardware path).
uint32_t Crc32cPortable(const void* data, size_t size, uint32_t crc);
// Whether Crc32c uses the SSE4.2 instruction on this CPU.
bool Crc32cHardwareAvailable();
}  // namespace internal

}  // namespace sope
