// gsenc as an ADIOS2 operator (ADIOS2 >= 2.12, plugin interface v2): a thin
// C++ shim over gsenc's C ABI, loaded by ADIOS2 from ADIOS2_PLUGIN_PATH when
// a variable's operation in the user's adios2.xml names it:
//
//   <variable name="rho">
//     <operation type="plugin">
//       <parameter key="PluginName" value="gsenc"/>
//       <parameter key="PluginLibrary" value="gsenc_adios2_operator"/>
//       <parameter key="budget" value="4000"/>   <!-- or target_psnr -->
//     </operation>
//   </variable>
//
// Put: a 3D float or double block of at least `min_elements` values is
// encoded into a gsenc model (the budget or target quality of the
// parameters), and the model's bytes are stored; any other block (other
// shapes and types, tiny blocks, a block whose model would not be smaller,
// one gsenc refuses, such as one holding NaN) is stored raw, never refused.
// Get: the model is decoded back onto the block's cells, in its type.
//
// Each stored block starts with this operator's own header (host byte
// order, checked by its magic on read):
//   0  "GSA2"           magic
//   4  u8  version      1
//   5  u8  mode         0 raw, 1 gsenc model
//   6  u8  type         adios2::DataType of the values
//   7  u8  ndims
//   8  u32 element size (bytes)
//  12  u32 reserved     0
//  16  u64 dims[ndims]  the block's count, slowest first (C order)
//   .  u64 budget       primitives of the model (0 raw)
//   .  u64 body bytes   the model file's bytes, or the raw values
//   .  body
//
// Parameters (all optional): budget (primitives, default one per 64
// values), target_psnr (dB; then budget is the most it may choose),
// schedule (full, matched, short, tuned; default matched), payload (f32,
// 8bit, 8bit-u16, packed; default packed), threads (default 0: every core),
// min_elements (default 4096). A parameter that is not one of these, or
// a bad value, is an error at the first Put.

#include "adios2/plugin/PluginOperatorInterface.h"
#include "gsenc.h"

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

namespace gsenc_adios2
{

using adios2::DataType;
using adios2::Dims;
using adios2::Params;

constexpr char kMagic[4] = {'G', 'S', 'A', '2'};
constexpr uint8_t kVersion = 1;
constexpr uint8_t kRaw = 0, kModel = 1;
constexpr size_t kFixedHeader = 16;

size_t ElementSize(DataType type)
{
    switch (type)
    {
    case DataType::Int8: case DataType::UInt8: case DataType::Char: return 1;
    case DataType::Int16: case DataType::UInt16: return 2;
    case DataType::Int32: case DataType::UInt32: case DataType::Float: return 4;
    case DataType::Int64: case DataType::UInt64: case DataType::Double: case DataType::FloatComplex: return 8;
    case DataType::LongDouble: case DataType::DoubleComplex: return 16;
    default: return 0;
    }
}

size_t HeaderSize(size_t ndims) { return kFixedHeader + 8 * ndims + 16; }

std::string LastError()
{
    std::string s(gsenc_last_error(nullptr, 0), '\0');
    gsenc_last_error(&s[0], s.size() + 1);
    return s;
}

// The settings of one operation, checked once.
struct Settings
{
    uint64_t budget = 0; // 0: one primitive per 64 values
    double target_psnr = 0.0;
    int32_t schedule = GSENC_SCHEDULE_MATCHED;
    int32_t payload = GSENC_PAYLOAD_PACKED;
    uint32_t threads = 0;
    int32_t backend = GSENC_BACKEND_AUTO;
    size_t min_elements = 4096;
};

uint64_t Number(const std::string &key, const std::string &value)
{
    size_t used = 0;
    unsigned long long v = 0;
    try { v = std::stoull(value, &used); } catch (const std::exception &) { used = 0; }
    if (used != value.size() || value.empty() || value[0] == '-')
        throw std::invalid_argument("gsenc ADIOS2 operator: " + key + " '" + value + "' is not a whole number");
    return v;
}

int32_t OneOf(const std::string &key, const std::string &value, const std::vector<std::pair<std::string, int32_t>> &names)
{
    std::string known;
    for (const auto &n : names)
    {
        if (n.first == value) return n.second;
        known += (known.empty() ? "" : ", ") + n.first;
    }
    throw std::invalid_argument("gsenc ADIOS2 operator: " + key + " '" + value + "' is not one of " + known);
}

Settings Parse(const Params &params)
{
    Settings s;
    for (const auto &kv : params)
    {
        // ADIOS2 hands the keys over in lower case.
        std::string k = kv.first;
        for (char &c : k) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
        const std::string &v = kv.second;
        if (k == "pluginname" || k == "pluginlibrary") continue; // ADIOS2's own
        if (k == "budget") s.budget = Number(k, v);
        else if (k == "target_psnr")
        {
            size_t used = 0;
            try { s.target_psnr = std::stod(v, &used); } catch (const std::exception &) { used = 0; }
            if (used != v.size() || v.empty() || !(s.target_psnr > 0.0 && s.target_psnr <= 120.0))
                throw std::invalid_argument("gsenc ADIOS2 operator: target_psnr '" + v + "' is not a PSNR in (0, 120] dB");
        }
        else if (k == "schedule")
            s.schedule = OneOf(k, v, {{"full", GSENC_SCHEDULE_FULL}, {"matched", GSENC_SCHEDULE_MATCHED}, {"short", GSENC_SCHEDULE_SHORT}, {"tuned", GSENC_SCHEDULE_TUNED}});
        else if (k == "payload")
            s.payload = OneOf(k, v, {{"f32", GSENC_PAYLOAD_F32}, {"8bit", GSENC_PAYLOAD_8BIT}, {"8bit-u16", GSENC_PAYLOAD_8BIT_U16}, {"packed", GSENC_PAYLOAD_PACKED}});
        else if (k == "threads") s.threads = static_cast<uint32_t>(Number(k, v));
        else if (k == "backend")
            s.backend = OneOf(k, v, {{"auto", GSENC_BACKEND_AUTO}, {"cpu", GSENC_BACKEND_CPU}, {"gpu", GSENC_BACKEND_GPU}});
        else if (k == "min_elements") s.min_elements = Number(k, v);
        else
            throw std::invalid_argument("gsenc ADIOS2 operator: unknown parameter '" + k +
                                        "' (budget, target_psnr, schedule, payload, threads, backend, min_elements)");
    }
    return s;
}

class Operator : public adios2::plugin::PluginOperatorInterface
{
public:
    explicit Operator(const Params &parameters) : PluginOperatorInterface(parameters) {}

    bool IsDataTypeValid(const DataType type) const override { return ElementSize(type) > 0; }

    size_t GetEstimatedSize(const size_t count, const size_t size, const size_t ndims, const size_t *) const override
    {
        return count * size + HeaderSize(ndims); // a raw block at worst
    }

    size_t Operate(const char *in, const Dims &start, const Dims &count, const DataType type, char *out) override
    {
        const Settings s = Parse(m_Parameters);
        size_t n = 1;
        for (size_t c : count) n *= c;
        const size_t esize = ElementSize(type), raw = n * esize, h = HeaderSize(count.size());
        if (esize == 0 || count.size() > 255)
            throw std::invalid_argument("gsenc ADIOS2 operator: a variable of this type or rank cannot be stored");
        bool encodable = count.size() == 3 && (type == DataType::Float || type == DataType::Double) && n >= s.min_elements;
        for (size_t c : count) encodable = encodable && c >= 2;
        uint64_t budget = 0, body = 0;
        if (encodable && Encode(s, in, start, count, type, out + h, raw, budget, body))
            return WriteHeader(out, kModel, type, count, esize, budget, body) + body;
        std::memcpy(out + h, in, raw);
        return WriteHeader(out, kRaw, type, count, esize, 0, raw) + raw;
    }

    size_t InverseOperate(const char *in, const size_t size, char *out) override
    {
        if (size < kFixedHeader || std::memcmp(in, kMagic, 4) != 0)
            throw std::runtime_error("gsenc ADIOS2 operator: not a block this operator wrote");
        if (static_cast<uint8_t>(in[4]) != kVersion)
            throw std::runtime_error("gsenc ADIOS2 operator: block version " + std::to_string(static_cast<uint8_t>(in[4])) + ", this operator reads 1");
        const uint8_t mode = static_cast<uint8_t>(in[5]), ndims = static_cast<uint8_t>(in[7]);
        const DataType type = static_cast<DataType>(static_cast<uint8_t>(in[6]));
        uint32_t esize = 0;
        std::memcpy(&esize, in + 8, 4);
        const size_t h = HeaderSize(ndims);
        if (size < h || esize == 0 || esize != ElementSize(type))
            throw std::runtime_error("gsenc ADIOS2 operator: a damaged block header");
        // ADIOS2 does not say how large `out` is: it holds the block's count
        // of values, which only this header says. So every field must agree
        // with every other (and the model's own lattice, below) before a
        // value is written: a damaged count would write past `out`.
        Dims count(ndims);
        size_t pos = kFixedHeader, n = 1;
        for (auto &c : count)
        {
            uint64_t v = 0;
            std::memcpy(&v, in + pos, 8);
            pos += 8;
            c = v;
            if (v != 0 && n > SIZE_MAX / esize / v)
                throw std::runtime_error("gsenc ADIOS2 operator: a damaged block header (its count overflows)");
            n *= c;
        }
        uint64_t budget = 0, body = 0;
        std::memcpy(&budget, in + pos, 8);
        std::memcpy(&body, in + pos + 8, 8);
        if (body > size - h)
            throw std::runtime_error("gsenc ADIOS2 operator: a truncated block");
        const char *data = in + h;
        if (mode == kRaw)
        {
            if (body != n * esize) throw std::runtime_error("gsenc ADIOS2 operator: a damaged raw block");
            std::memcpy(out, data, body);
            return body;
        }
        if (mode != kModel || ndims != 3 || (type != DataType::Float && type != DataType::Double))
            throw std::runtime_error("gsenc ADIOS2 operator: a damaged block header");
        gsenc_model *model = nullptr;
        if (gsenc_model_read_buffer(reinterpret_cast<const uint8_t *>(data), body, &model) != GSENC_STATUS_OK)
            throw std::runtime_error("gsenc ADIOS2 operator: " + LastError());
        const uint64_t dims[3] = {count[2], count[1], count[0]}; // x fastest
        // The model was encoded from this very block, so its lattice is the
        // block's count (the model's bytes are checked by their CRC).
        gsenc_model_info info;
        std::memset(&info, 0, sizeof info);
        info.struct_size = sizeof info;
        if (gsenc_model_info_get(model, &info) != GSENC_STATUS_OK || !std::equal(dims, dims + 3, info.dims))
        {
            gsenc_model_destroy(model);
            throw std::runtime_error("gsenc ADIOS2 operator: a damaged block header (its count is not its model's lattice)");
        }
        std::vector<float> decoded(type == DataType::Double ? n : 0);
        float *target = type == DataType::Float ? reinterpret_cast<float *>(out) : decoded.data();
        const gsenc_status st = gsenc_model_decode(model, dims, target, n);
        gsenc_model_destroy(model);
        if (st != GSENC_STATUS_OK) throw std::runtime_error("gsenc ADIOS2 operator: " + LastError());
        if (type == DataType::Double)
        {
            double *d = reinterpret_cast<double *>(out);
            for (size_t i = 0; i < n; i++) d[i] = decoded[i];
        }
        return n * esize;
    }

private:
    static size_t WriteHeader(char *out, uint8_t mode, DataType type, const Dims &count, size_t esize, uint64_t budget, uint64_t body)
    {
        std::memcpy(out, kMagic, 4);
        out[4] = static_cast<char>(kVersion);
        out[5] = static_cast<char>(mode);
        out[6] = static_cast<char>(static_cast<uint8_t>(type));
        out[7] = static_cast<char>(static_cast<uint8_t>(count.size()));
        const uint32_t e = static_cast<uint32_t>(esize), zero = 0;
        std::memcpy(out + 8, &e, 4);
        std::memcpy(out + 12, &zero, 4);
        size_t pos = kFixedHeader;
        for (size_t c : count)
        {
            const uint64_t v = c;
            std::memcpy(out + pos, &v, 8);
            pos += 8;
        }
        std::memcpy(out + pos, &budget, 8);
        std::memcpy(out + pos + 8, &body, 8);
        return pos + 16;
    }

    // Encodes the block into `out` (at most `capacity` bytes); false, with
    // the reason on stderr, when it stays raw.
    static bool Encode(const Settings &s, const char *in, const Dims &start, const Dims &count, DataType type, char *out,
                       size_t capacity, uint64_t &budget, uint64_t &body)
    {
        size_t n = 1;
        for (size_t c : count) n *= c;
        gsenc_config cfg;
        std::memset(&cfg, 0, sizeof cfg);
        cfg.struct_size = sizeof cfg;
        gsenc_config_init(&cfg);
        cfg.budget = s.target_psnr > 0.0 && s.budget == 0 ? 0 : (s.budget ? s.budget : std::max<uint64_t>(16, n / 64));
        cfg.target_psnr = s.target_psnr;
        cfg.schedule = s.schedule;
        cfg.payload = s.payload;
        cfg.threads = s.threads;
        cfg.backend = s.backend;
        cfg.warm_start = GSENC_WARM_OFF;
        gsenc_grid grid;
        std::memset(&grid, 0, sizeof grid);
        grid.struct_size = sizeof grid;
        grid.dtype = type == DataType::Float ? GSENC_DTYPE_FLOAT32 : GSENC_DTYPE_FLOAT64;
        grid.data = in;
        grid.extents[0] = count[2];
        grid.extents[1] = count[1];
        grid.extents[2] = count[0];
        grid.strides[0] = 1;
        grid.strides[1] = static_cast<int64_t>(count[2]);
        grid.strides[2] = static_cast<int64_t>(count[2] * count[1]);
        grid.origin[0] = static_cast<double>(start[2]);
        grid.origin[1] = static_cast<double>(start[1]);
        grid.origin[2] = static_cast<double>(start[0]);
        grid.spacing = 1.0;

        gsenc_encoder *enc = nullptr;
        size_t size = 0;
        bool ok = gsenc_encoder_create(&cfg, &enc) == GSENC_STATUS_OK &&
                  gsenc_push_grid(enc, "block", 0, 0.0, &grid) == GSENC_STATUS_OK &&
                  gsenc_wait(enc, "block") == GSENC_STATUS_OK &&
                  gsenc_encoder_model_bytes(enc, "block", nullptr, 0, &size) == GSENC_STATUS_OK;
        std::string why = ok ? "" : LastError();
        if (ok && size >= capacity)
        {
            ok = false;
            why = "its model (" + std::to_string(size) + " bytes) is not smaller than its values";
        }
        if (ok) ok = gsenc_encoder_model_bytes(enc, "block", reinterpret_cast<uint8_t *>(out), capacity, &size) == GSENC_STATUS_OK;
        gsenc_model *model = nullptr;
        gsenc_model_info info;
        std::memset(&info, 0, sizeof info);
        info.struct_size = sizeof info;
        if (ok) ok = gsenc_model_read_buffer(reinterpret_cast<const uint8_t *>(out), size, &model) == GSENC_STATUS_OK &&
                     gsenc_model_info_get(model, &info) == GSENC_STATUS_OK;
        if (!ok && why.empty()) why = LastError();
        gsenc_model_destroy(model);
        gsenc_encoder_destroy(enc);
        if (!ok)
        {
            std::fprintf(stderr, "gsenc ADIOS2 operator: a block stored raw: %s\n", why.c_str());
            return false;
        }
        budget = info.count;
        body = size;
        return true;
    }
};

} // namespace gsenc_adios2

extern "C" {
adios2::plugin::PluginOperatorInterface *OperatorCreate(const adios2::Params &parameters)
{
    return new gsenc_adios2::Operator(parameters);
}

void OperatorDestroy(adios2::plugin::PluginOperatorInterface *obj) { delete obj; }
}
