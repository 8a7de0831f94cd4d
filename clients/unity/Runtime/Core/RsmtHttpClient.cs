// HTTP calls of the contract that a game needs (style registration, model info), with retries on 429
// (honouring Retry-After) and 503. System.Net.Http works in the Editor and on desktop/mobile players;
// in WebGL use UnityWebRequest with the same JSON bodies (RsmtMessages / Json.Quote build them).
using System;
using System.Collections.Generic;
using System.Globalization;
using System.Net;
using System.Net.Http;
using System.Text;
using System.Threading.Tasks;

namespace Rsmt.Link
{
    public sealed class RsmtStyleInfo
    {
        public string StyleId;
        public string Name;
        public int Frames;
        public int Clips = 1;
        public bool Cached;
    }

    public sealed class RsmtHttpException : Exception
    {
        public readonly int Status;
        public readonly string Code;
        public RsmtHttpException(int status, string code, string message) : base(status + " " + code + ": " + message)
        {
            Status = status;
            Code = code;
        }
    }

    public sealed class RsmtHttpClient : IDisposable
    {
        readonly HttpClient http;
        readonly string baseUrl;

        public int Attempts = 5;
        public double BackoffSeconds = 0.25;
        public double MaxRetryAfterSeconds = 60;
        /// <summary>Called before each retry with (attempt, seconds to wait).</summary>
        public Action<int, double> OnRetry;

        public RsmtHttpClient(string baseUrl, string apiKey = null, double timeoutSeconds = 60)
        {
            this.baseUrl = baseUrl.TrimEnd('/');
            http = new HttpClient { Timeout = TimeSpan.FromSeconds(timeoutSeconds) };
            if (!string.IsNullOrEmpty(apiKey)) http.DefaultRequestHeaders.Add("X-API-Key", apiKey);
        }

        public async Task<JsonValue> SendAsync(HttpMethod method, string path, string jsonBody = null)
        {
            for (int attempt = 0; ; attempt++)
            {
                var request = new HttpRequestMessage(method, baseUrl + path);
                if (jsonBody != null) request.Content = new StringContent(jsonBody, Encoding.UTF8, "application/json");
                using (var response = await http.SendAsync(request).ConfigureAwait(false))
                {
                    string text = await response.Content.ReadAsStringAsync().ConfigureAwait(false);
                    int status = (int)response.StatusCode;
                    if (status < 400) return string.IsNullOrEmpty(text) ? JsonValue.Null : Json.Parse(text);
                    double wait = -1;
                    if ((status == 429 || status == 503) && attempt + 1 < Attempts)
                    {
                        wait = BackoffSeconds * Math.Pow(2, attempt);
                        var after = response.Headers.RetryAfter;
                        if (after != null && after.Delta.HasValue) wait = after.Delta.Value.TotalSeconds;
                        else if (after != null && after.Date.HasValue) wait = Math.Max(0, (after.Date.Value - DateTimeOffset.UtcNow).TotalSeconds);
                        if (wait > MaxRetryAfterSeconds) wait = -1;
                    }
                    if (wait < 0)
                    {
                        string code = "http_error", message = text;
                        JsonValue body, error;
                        string ignored;
                        if (Json.TryParse(text, out body, out ignored) && (error = body.Get("error")) != null)
                        {
                            code = error.GetString("code", code);
                            message = error.GetString("message", message);
                        }
                        throw new RsmtHttpException(status, code, message);
                    }
                    if (OnRetry != null) OnRetry(attempt, wait);
                    await Task.Delay(TimeSpan.FromSeconds(wait)).ConfigureAwait(false);
                }
            }
        }

        /// <summary>What the model reads of a motion; fetched with GET /v1/model on the first registration when null.</summary>
        public RsmtMotionCutter Cutter;

        /// <summary>POST /v1/styles. A clip longer than the model reads is cut to its middle (Cutter.Notice says so once).</summary>
        public async Task<RsmtStyleInfo> RegisterStyleAsync(string bvhText, string name)
        {
            if (Cutter == null) Cutter = new RsmtMotionCutter(RsmtMotionLimits.FromModel(await ModelAsync().ConfigureAwait(false)));
            bvhText = Cutter.Style(bvhText);
            string body = "{\"name\":" + Json.Quote(name) + ",\"motion\":" + RsmtMessages.BvhMotion(bvhText) + "}";
            var json = await SendAsync(HttpMethod.Post, "/v1/styles", body).ConfigureAwait(false);
            return StyleInfo(json, name);
        }

        /// <summary>POST /v1/styles with 1 to 5 clips of one style, encoded together into one style (the same clips in
        /// any order get the same id); each clip is cut as RegisterStyleAsync cuts one.</summary>
        public async Task<RsmtStyleInfo> RegisterStyleClipsAsync(IList<string> bvhTexts, string name)
        {
            if (bvhTexts == null || bvhTexts.Count < 1 || bvhTexts.Count > MaxStyleClips)
                throw new ArgumentException("a style is registered from 1 to " + MaxStyleClips + " clips; got "
                                            + (bvhTexts == null ? 0 : bvhTexts.Count));
            if (Cutter == null) Cutter = new RsmtMotionCutter(RsmtMotionLimits.FromModel(await ModelAsync().ConfigureAwait(false)));
            var motions = new List<string>();
            foreach (var bvh in bvhTexts) motions.Add(RsmtMessages.BvhMotion(Cutter.Style(bvh)));
            string body = "{\"name\":" + Json.Quote(name) + ",\"motions\":[" + string.Join(",", motions) + "]}";
            return StyleInfo(await SendAsync(HttpMethod.Post, "/v1/styles", body).ConfigureAwait(false), name);
        }

        /// <summary>The most clips one style is registered from.</summary>
        public const int MaxStyleClips = 5;

        static RsmtStyleInfo StyleInfo(JsonValue json, string name)
        {
            return new RsmtStyleInfo
            {
                StyleId = json.GetString("style_id", null),
                Name = json.GetString("name", name),
                Frames = json.GetInt("frames", 0),
                Clips = json.GetInt("clips", 1),
                Cached = json.GetBool("cached", false),
            };
        }

        public async Task<RsmtModelInfo> ModelAsync()
        {
            return RsmtModelInfo.FromJson(await SendAsync(HttpMethod.Get, "/v1/model").ConfigureAwait(false));
        }

        public void Dispose() { http.Dispose(); }
    }
}
