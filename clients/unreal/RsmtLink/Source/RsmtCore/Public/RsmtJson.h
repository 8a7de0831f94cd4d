// A small JSON reader and string escaper: enough for the RSMT wire protocol, no exceptions, no RTTI.
#pragma once

#include <cstddef>
#include <string>
#include <utility>
#include <vector>

#include "RsmtCoreApi.h"

namespace rsmt {

class RSMTCORE_API JsonValue {
public:
    enum class Type { Null, Bool, Number, String, Array, Object };

    Type type = Type::Null;
    bool boolean = false;
    double number = 0.0;
    std::string string;
    std::vector<JsonValue> array;
    std::vector<std::pair<std::string, JsonValue>> object;  // in document order

    bool IsNull() const { return type == Type::Null; }
    bool IsNumber() const { return type == Type::Number; }
    bool IsString() const { return type == Type::String; }
    bool IsArray() const { return type == Type::Array; }
    bool IsObject() const { return type == Type::Object; }

    // The member named key, or nullptr (also when this is not an object).
    const JsonValue* Find(const std::string& key) const;
    double NumberOr(const std::string& key, double fallback) const;
    std::string StringOr(const std::string& key, const std::string& fallback) const;
};

// Parses one JSON document (RFC 8259; nesting up to 64 levels). On failure returns false and,
// when error is given, says what and at which byte.
RSMTCORE_API bool ParseJson(const char* data, std::size_t size, JsonValue& out, std::string* error = nullptr);
RSMTCORE_API bool ParseJson(const std::string& text, JsonValue& out, std::string* error = nullptr);

// text as a JSON string literal, quotes included (UTF-8 passes through; control characters are escaped).
RSMTCORE_API std::string JsonQuote(const std::string& text);

// A number as JSON text that reads back to the same double (shortest round-trip with %.17g fallback).
RSMTCORE_API std::string JsonNumber(double value);

}  // namespace rsmt
