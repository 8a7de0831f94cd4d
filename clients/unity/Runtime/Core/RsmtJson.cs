// A small JSON reader and writer for the RSMT protocol (no UnityEngine, no System.Text.Json: Unity's
// JsonUtility cannot read nested arrays, and Mono/older Unity profiles lack System.Text.Json).
using System;
using System.Collections.Generic;
using System.Globalization;
using System.Text;

namespace Rsmt.Link
{
    public enum JsonType { Null, Bool, Number, String, Array, Object }

    public sealed class JsonValue
    {
        public JsonType Type;
        public bool Bool;
        public double Number;
        public string String;
        public List<JsonValue> Array;
        public List<KeyValuePair<string, JsonValue>> Object;

        public static readonly JsonValue Null = new JsonValue { Type = JsonType.Null };

        public bool IsNull { get { return Type == JsonType.Null; } }

        /// <summary>The member named key, or null (also when this is not an object).</summary>
        public JsonValue Get(string key)
        {
            if (Type != JsonType.Object) return null;
            for (int i = 0; i < Object.Count; i++)
            {
                if (Object[i].Key == key) return Object[i].Value;
            }
            return null;
        }

        public double GetNumber(string key, double fallback)
        {
            var v = Get(key);
            return v != null && v.Type == JsonType.Number ? v.Number : fallback;
        }

        public int GetInt(string key, int fallback)
        {
            var v = Get(key);
            return v != null && v.Type == JsonType.Number ? (int)Math.Round(v.Number) : fallback;
        }

        public string GetString(string key, string fallback)
        {
            var v = Get(key);
            return v != null && v.Type == JsonType.String ? v.String : fallback;
        }

        public bool GetBool(string key, bool fallback)
        {
            var v = Get(key);
            return v != null && v.Type == JsonType.Bool ? v.Bool : fallback;
        }
    }

    public sealed class JsonException : Exception
    {
        public JsonException(string message) : base(message) { }
    }

    public static class Json
    {
        const int MaxDepth = 64;

        /// <summary>Parses one JSON document; throws JsonException saying what and where.</summary>
        public static JsonValue Parse(string text)
        {
            int pos = 0;
            SkipSpace(text, ref pos);
            var value = ParseValue(text, ref pos, 0);
            SkipSpace(text, ref pos);
            if (pos != text.Length) throw Error("unexpected text after the JSON value", pos);
            return value;
        }

        public static bool TryParse(string text, out JsonValue value, out string error)
        {
            try
            {
                value = Parse(text);
                error = null;
                return true;
            }
            catch (JsonException e)
            {
                value = null;
                error = e.Message;
                return false;
            }
        }

        static JsonException Error(string what, int pos)
        {
            return new JsonException(what + " at character " + pos.ToString(CultureInfo.InvariantCulture));
        }

        static void SkipSpace(string s, ref int pos)
        {
            while (pos < s.Length && (s[pos] == ' ' || s[pos] == '\t' || s[pos] == '\n' || s[pos] == '\r')) pos++;
        }

        static JsonValue ParseValue(string s, ref int pos, int depth)
        {
            if (depth > MaxDepth) throw Error("nesting deeper than 64 levels", pos);
            if (pos >= s.Length) throw Error("unexpected end of input", pos);
            char c = s[pos];
            switch (c)
            {
                case '{': return ParseObject(s, ref pos, depth);
                case '[': return ParseArray(s, ref pos, depth);
                case '"': return new JsonValue { Type = JsonType.String, String = ParseString(s, ref pos) };
                case 't': Expect(s, ref pos, "true"); return new JsonValue { Type = JsonType.Bool, Bool = true };
                case 'f': Expect(s, ref pos, "false"); return new JsonValue { Type = JsonType.Bool, Bool = false };
                case 'n': Expect(s, ref pos, "null"); return new JsonValue { Type = JsonType.Null };
                default: return ParseNumber(s, ref pos);
            }
        }

        static void Expect(string s, ref int pos, string word)
        {
            if (string.CompareOrdinal(s, pos, word, 0, word.Length) != 0) throw Error("invalid literal", pos);
            pos += word.Length;
        }

        static JsonValue ParseObject(string s, ref int pos, int depth)
        {
            var v = new JsonValue { Type = JsonType.Object, Object = new List<KeyValuePair<string, JsonValue>>() };
            pos++;
            SkipSpace(s, ref pos);
            if (pos < s.Length && s[pos] == '}') { pos++; return v; }
            while (true)
            {
                SkipSpace(s, ref pos);
                if (pos >= s.Length || s[pos] != '"') throw Error("expected a member name", pos);
                string key = ParseString(s, ref pos);
                SkipSpace(s, ref pos);
                if (pos >= s.Length || s[pos] != ':') throw Error("expected ':'", pos);
                pos++;
                SkipSpace(s, ref pos);
                v.Object.Add(new KeyValuePair<string, JsonValue>(key, ParseValue(s, ref pos, depth + 1)));
                SkipSpace(s, ref pos);
                if (pos < s.Length && s[pos] == ',') { pos++; continue; }
                if (pos < s.Length && s[pos] == '}') { pos++; return v; }
                throw Error("expected ',' or '}'", pos);
            }
        }

        static JsonValue ParseArray(string s, ref int pos, int depth)
        {
            var v = new JsonValue { Type = JsonType.Array, Array = new List<JsonValue>() };
            pos++;
            SkipSpace(s, ref pos);
            if (pos < s.Length && s[pos] == ']') { pos++; return v; }
            while (true)
            {
                SkipSpace(s, ref pos);
                v.Array.Add(ParseValue(s, ref pos, depth + 1));
                SkipSpace(s, ref pos);
                if (pos < s.Length && s[pos] == ',') { pos++; continue; }
                if (pos < s.Length && s[pos] == ']') { pos++; return v; }
                throw Error("expected ',' or ']'", pos);
            }
        }

        static string ParseString(string s, ref int pos)
        {
            pos++;  // opening quote
            StringBuilder sb = null;
            int start = pos;
            while (pos < s.Length)
            {
                char c = s[pos];
                if (c == '"')
                {
                    string result = sb == null ? s.Substring(start, pos - start) : sb.Append(s, start, pos - start).ToString();
                    pos++;
                    return result;
                }
                if (c < 0x20) throw Error("control character in a string", pos);
                if (c != '\\') { pos++; continue; }
                if (sb == null) sb = new StringBuilder();
                sb.Append(s, start, pos - start);
                pos++;
                if (pos >= s.Length) break;
                char e = s[pos++];
                switch (e)
                {
                    case '"': sb.Append('"'); break;
                    case '\\': sb.Append('\\'); break;
                    case '/': sb.Append('/'); break;
                    case 'b': sb.Append('\b'); break;
                    case 'f': sb.Append('\f'); break;
                    case 'n': sb.Append('\n'); break;
                    case 'r': sb.Append('\r'); break;
                    case 't': sb.Append('\t'); break;
                    case 'u':
                        if (pos + 4 > s.Length) throw Error("truncated \\u escape", pos);
                        int code;
                        if (!int.TryParse(s.Substring(pos, 4), NumberStyles.AllowHexSpecifier, CultureInfo.InvariantCulture, out code))
                            throw Error("invalid \\u escape", pos);
                        sb.Append((char)code);  // surrogate pairs stay as two UTF-16 units, as C# strings want
                        pos += 4;
                        break;
                    default: throw Error("invalid escape", pos - 1);
                }
                start = pos;
            }
            throw Error("unterminated string", pos);
        }

        static JsonValue ParseNumber(string s, ref int pos)
        {
            int start = pos;
            if (pos < s.Length && s[pos] == '-') pos++;
            if (pos >= s.Length || s[pos] < '0' || s[pos] > '9') throw Error("invalid value", start);
            while (pos < s.Length && ((s[pos] >= '0' && s[pos] <= '9') || s[pos] == '.' || s[pos] == 'e' || s[pos] == 'E' ||
                                      s[pos] == '+' || s[pos] == '-')) pos++;
            double d;
            if (!double.TryParse(s.Substring(start, pos - start), NumberStyles.Float, CultureInfo.InvariantCulture, out d) ||
                double.IsInfinity(d) || double.IsNaN(d))
                throw Error("invalid number", start);
            return new JsonValue { Type = JsonType.Number, Number = d };
        }

        /// <summary>text as a JSON string literal, quotes included.</summary>
        public static string Quote(string text)
        {
            var sb = new StringBuilder(text.Length + 2);
            sb.Append('"');
            foreach (char c in text)
            {
                switch (c)
                {
                    case '"': sb.Append("\\\""); break;
                    case '\\': sb.Append("\\\\"); break;
                    case '\n': sb.Append("\\n"); break;
                    case '\r': sb.Append("\\r"); break;
                    case '\t': sb.Append("\\t"); break;
                    default:
                        if (c < 0x20) sb.Append("\\u").Append(((int)c).ToString("x4", CultureInfo.InvariantCulture));
                        else sb.Append(c);
                        break;
                }
            }
            return sb.Append('"').ToString();
        }

        /// <summary>A number as JSON text that reads back to the same double, whatever the culture.</summary>
        public static string Number(double value)
        {
            if (double.IsNaN(value) || double.IsInfinity(value)) return "null";
            return value.ToString("R", CultureInfo.InvariantCulture);
        }
    }
}
