#include "RsmtReassembler.h"

namespace rsmt {

void MessageAssembler::Reset() {
    buffer_.clear();
    complete_ = false;
    overflow_ = false;
}

MessageAssembler::Result MessageAssembler::Feed(const void* data, std::size_t size, std::size_t bytesRemaining) {
    return FeedFragment(data, size, bytesRemaining == 0);
}

MessageAssembler::Result MessageAssembler::FeedFragment(const void* data, std::size_t size, bool last) {
    if (complete_) {  // the previous message was handed out: start a new one
        buffer_.clear();
        complete_ = false;
    }
    if (!overflow_) {
        if (buffer_.size() + size > maxBytes_) {
            overflow_ = true;
            buffer_.clear();
            buffer_.shrink_to_fit();
        } else if (size > 0) {
            const std::uint8_t* bytes = static_cast<const std::uint8_t*>(data);
            buffer_.insert(buffer_.end(), bytes, bytes + size);
        }
    }
    if (!last) return Result::Partial;
    if (overflow_) {
        overflow_ = false;
        buffer_.clear();
        return Result::TooLarge;
    }
    complete_ = true;
    return Result::Complete;
}

PayloadKind ClassifyMessage(const std::uint8_t* data, std::size_t size) {
    for (std::size_t i = 0; i < size; ++i) {
        const std::uint8_t c = data[i];
        if (c == ' ' || c == '\t' || c == '\r' || c == '\n') continue;  // JSON may start with whitespace
        return c == '{' ? PayloadKind::Text : PayloadKind::Binary;
    }
    return PayloadKind::Binary;
}

}  // namespace rsmt
