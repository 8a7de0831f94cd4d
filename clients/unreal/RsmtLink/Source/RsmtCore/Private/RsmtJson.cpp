#include "RsmtJson.h"

#include <clocale>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>

namespace rsmt {

const JsonValue* JsonValue::Find(const std::string& key) const {
    if (type != Type::Object) return nullptr;
    for (const auto& member : object) {
        if (member.first == key) return &member.second;
    }
    return nullptr;
}

double JsonValue::NumberOr(const std::string& key, double fallback) const {
    const JsonValue* v = Find(key);
    return v != nullptr && v->IsNumber() ? v->number : fallback;
}

std::string JsonValue::StringOr(const std::string& key, const std::string& fallback) const {
    const JsonValue* v = Find(key);
    return v != nullptr && v->IsString() ? v->string : fallback;
}

namespace {

class Parser {
public:
    Parser(const char* data, std::size_t size) : p_(data), begin_(data), end_(data + size) {}

    bool Document(JsonValue& out, std::string* error) {
        SkipSpace();
        if (!Value(out, 0)) return Fail(error);
        SkipSpace();
        if (p_ != end_) {
            problem_ = "unexpected text after the JSON value";
            return Fail(error);
        }
        return true;
    }

private:
    const char* p_;
    const char* begin_;
    const char* end_;
    const char* problem_ = nullptr;

    bool Fail(std::string* error) {
        if (error != nullptr) {
            *error = std::string(problem_ != nullptr ? problem_ : "invalid JSON") + " at byte " +
                     std::to_string(static_cast<long long>(p_ - begin_));
        }
        return false;
    }

    bool Error(const char* what) {
        if (problem_ == nullptr) problem_ = what;
        return false;
    }

    void SkipSpace() {
        while (p_ < end_ && (*p_ == ' ' || *p_ == '\t' || *p_ == '\n' || *p_ == '\r')) ++p_;
    }

    bool Literal(const char* word, std::size_t length) {
        if (static_cast<std::size_t>(end_ - p_) < length || std::memcmp(p_, word, length) != 0) {
            return Error("invalid literal");
        }
        p_ += length;
        return true;
    }

    bool Value(JsonValue& out, int depth) {
        if (depth > 64) return Error("nesting deeper than 64 levels");
        if (p_ >= end_) return Error("unexpected end of input");
        switch (*p_) {
            case '{': return Object(out, depth);
            case '[': return Array(out, depth);
            case '"': out.type = JsonValue::Type::String; return String(out.string);
            case 't': out.type = JsonValue::Type::Bool; out.boolean = true; return Literal("true", 4);
            case 'f': out.type = JsonValue::Type::Bool; out.boolean = false; return Literal("false", 5);
            case 'n': out.type = JsonValue::Type::Null; return Literal("null", 4);
            default: return Number(out);
        }
    }

    bool Object(JsonValue& out, int depth) {
        out.type = JsonValue::Type::Object;
        ++p_;
        SkipSpace();
        if (p_ < end_ && *p_ == '}') {
            ++p_;
            return true;
        }
        for (;;) {
            SkipSpace();
            if (p_ >= end_ || *p_ != '"') return Error("expected a member name");
            std::string key;
            if (!String(key)) return false;
            SkipSpace();
            if (p_ >= end_ || *p_ != ':') return Error("expected ':'");
            ++p_;
            SkipSpace();
            out.object.emplace_back(std::move(key), JsonValue());
            if (!Value(out.object.back().second, depth + 1)) return false;
            SkipSpace();
            if (p_ < end_ && *p_ == ',') {
                ++p_;
                continue;
            }
            if (p_ < end_ && *p_ == '}') {
                ++p_;
                return true;
            }
            return Error("expected ',' or '}'");
        }
    }

    bool Array(JsonValue& out, int depth) {
        out.type = JsonValue::Type::Array;
        ++p_;
        SkipSpace();
        if (p_ < end_ && *p_ == ']') {
            ++p_;
            return true;
        }
        for (;;) {
            SkipSpace();
            out.array.emplace_back();
            if (!Value(out.array.back(), depth + 1)) return false;
            SkipSpace();
            if (p_ < end_ && *p_ == ',') {
                ++p_;
                continue;
            }
            if (p_ < end_ && *p_ == ']') {
                ++p_;
                return true;
            }
            return Error("expected ',' or ']'");
        }
    }

    static void AppendUtf8(std::string& s, unsigned long cp) {
        if (cp < 0x80) {
            s += static_cast<char>(cp);
        } else if (cp < 0x800) {
            s += static_cast<char>(0xC0 | (cp >> 6));
            s += static_cast<char>(0x80 | (cp & 0x3F));
        } else if (cp < 0x10000) {
            s += static_cast<char>(0xE0 | (cp >> 12));
            s += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
            s += static_cast<char>(0x80 | (cp & 0x3F));
        } else {
            s += static_cast<char>(0xF0 | (cp >> 18));
            s += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
            s += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
            s += static_cast<char>(0x80 | (cp & 0x3F));
        }
    }

    bool Hex4(unsigned long& out) {
        if (end_ - p_ < 4) return Error("truncated \\u escape");
        out = 0;
        for (int i = 0; i < 4; ++i) {
            const char c = *p_++;
            out <<= 4;
            if (c >= '0' && c <= '9') out |= static_cast<unsigned long>(c - '0');
            else if (c >= 'a' && c <= 'f') out |= static_cast<unsigned long>(c - 'a' + 10);
            else if (c >= 'A' && c <= 'F') out |= static_cast<unsigned long>(c - 'A' + 10);
            else return Error("invalid \\u escape");
        }
        return true;
    }

    bool String(std::string& out) {
        ++p_;  // opening quote
        out.clear();
        while (p_ < end_) {
            const char c = *p_++;
            if (c == '"') return true;
            if (static_cast<unsigned char>(c) < 0x20) return Error("control character in a string");
            if (c != '\\') {
                out += c;
                continue;
            }
            if (p_ >= end_) break;
            const char e = *p_++;
            switch (e) {
                case '"': out += '"'; break;
                case '\\': out += '\\'; break;
                case '/': out += '/'; break;
                case 'b': out += '\b'; break;
                case 'f': out += '\f'; break;
                case 'n': out += '\n'; break;
                case 'r': out += '\r'; break;
                case 't': out += '\t'; break;
                case 'u': {
                    unsigned long cp = 0;
                    if (!Hex4(cp)) return false;
                    if (cp >= 0xD800 && cp < 0xDC00) {  // a surrogate pair
                        unsigned long low = 0;
                        if (end_ - p_ < 6 || p_[0] != '\\' || p_[1] != 'u') return Error("lone surrogate");
                        p_ += 2;
                        if (!Hex4(low) || low < 0xDC00 || low > 0xDFFF) return Error("invalid surrogate pair");
                        cp = 0x10000 + ((cp - 0xD800) << 10) + (low - 0xDC00);
                    }
                    AppendUtf8(out, cp);
                    break;
                }
                default: return Error("invalid escape");
            }
        }
        return Error("unterminated string");
    }

    bool Number(JsonValue& out) {
        const char* start = p_;
        if (p_ < end_ && *p_ == '-') ++p_;
        if (p_ >= end_ || !(*p_ >= '0' && *p_ <= '9')) return Error("invalid value");
        while (p_ < end_ && ((*p_ >= '0' && *p_ <= '9') || *p_ == '.' || *p_ == 'e' || *p_ == 'E' || *p_ == '+' ||
                             *p_ == '-')) {
            ++p_;
        }
        // strtod reads the C locale's decimal point only when the process locale says so: swap it in.
        std::string text(start, p_);
        const char* point = std::localeconv()->decimal_point;
        if (point != nullptr && point[0] != '.' && point[0] != '\0') {
            for (char& ch : text) {
                if (ch == '.') ch = point[0];
            }
        }
        char* stop = nullptr;
        const double value = std::strtod(text.c_str(), &stop);
        if (stop != text.c_str() + text.size() || !std::isfinite(value)) {
            p_ = start;
            return Error("invalid number");
        }
        out.type = JsonValue::Type::Number;
        out.number = value;
        return true;
    }
};

}  // namespace

bool ParseJson(const char* data, std::size_t size, JsonValue& out, std::string* error) {
    out = JsonValue();
    Parser parser(data, size);
    return parser.Document(out, error);
}

bool ParseJson(const std::string& text, JsonValue& out, std::string* error) {
    return ParseJson(text.data(), text.size(), out, error);
}

std::string JsonQuote(const std::string& text) {
    std::string out;
    out.reserve(text.size() + 2);
    out += '"';
    for (const char c : text) {
        switch (c) {
            case '"': out += "\\\""; break;
            case '\\': out += "\\\\"; break;
            case '\n': out += "\\n"; break;
            case '\r': out += "\\r"; break;
            case '\t': out += "\\t"; break;
            default:
                if (static_cast<unsigned char>(c) < 0x20) {
                    char buf[8];
                    std::snprintf(buf, sizeof buf, "\\u%04x", static_cast<unsigned>(static_cast<unsigned char>(c)));
                    out += buf;
                } else {
                    out += c;
                }
        }
    }
    out += '"';
    return out;
}

std::string JsonNumber(double value) {
    if (!std::isfinite(value)) return "null";
    char buf[40];
    for (int precision = 9; precision <= 17; ++precision) {
        std::snprintf(buf, sizeof buf, "%.*g", precision, value);
        if (std::strtod(buf, nullptr) == value) break;
    }
    std::string text(buf);
    const char* point = std::localeconv()->decimal_point;
    if (point != nullptr && point[0] != '.' && point[0] != '\0') {
        for (char& ch : text) {
            if (ch == point[0]) ch = '.';
        }
    }
    return text;
}

}  // namespace rsmt
