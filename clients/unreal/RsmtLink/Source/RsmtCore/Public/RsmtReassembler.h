// Reassembly of WebSocket messages that arrive in pieces.
//
// Unreal's IWebSocket::OnRawMessage(Data, Size, BytesRemaining) hands over a message in chunks
// (libwebsockets delivers large frames in pieces; BytesRemaining counts what is still to come)
// and, depending on the platform implementation, for text messages as well as binary ones.
// MessageAssembler joins the pieces; ClassifyMessage then tells text from binary.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "RsmtCoreApi.h"

namespace rsmt {

class RSMTCORE_API MessageAssembler {
public:
    enum class Result { Partial, Complete, TooLarge };

    explicit MessageAssembler(std::size_t maxBytes = 1u << 20) : maxBytes_(maxBytes) {}

    // One OnRawMessage call. Complete: Data() holds the whole message until the next call.
    // TooLarge: the message passed maxBytes and was dropped (reported once, on its last piece).
    Result Feed(const void* data, std::size_t size, std::size_t bytesRemaining);
    // One OnBinaryMessage(Data, Size, bIsLastFragment) call, for engines that offer it.
    Result FeedFragment(const void* data, std::size_t size, bool last);

    const std::vector<std::uint8_t>& Data() const { return buffer_; }
    void Reset();
    void SetMaxBytes(std::size_t maxBytes) { maxBytes_ = maxBytes; }

private:
    std::vector<std::uint8_t> buffer_;
    std::size_t maxBytes_;
    bool complete_ = false;
    bool overflow_ = false;
};

enum class PayloadKind { Text, Binary };

// The server's text messages are JSON objects, so they begin with '{' (0x7B). A binary frame begins
// with the float32 slot number, whose first (least significant) byte is 0 for every slot below 2^16.
RSMTCORE_API PayloadKind ClassifyMessage(const std::uint8_t* data, std::size_t size);

}  // namespace rsmt
