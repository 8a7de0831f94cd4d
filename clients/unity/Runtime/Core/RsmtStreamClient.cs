// The engine-independent stream client: a transport, the protocol session, coordinate conversion to Unity
// axes and one jitter buffer per character. Everything except ConnectAsync runs on the thread that calls
// Dispatch (Unity: the main thread, from Update), so event handlers may touch Transforms.
using System;
using System.Collections.Generic;
using System.Threading;
using System.Threading.Tasks;

namespace Rsmt.Link
{
    public sealed class RsmtStreamClient : IDisposable
    {
        readonly IRsmtTransport transport;
        readonly RsmtSession session = new RsmtSession();
        readonly Dictionary<string, RsmtJitterBuffer> buffers = new Dictionary<string, RsmtJitterBuffer>();
        int nextId;

        /// <summary>Seconds frames wait before they play (new characters take it from here).</summary>
        public double BufferDelay;
        /// <summary>Metres per model unit, from hello's skeleton.units (0.01 for centimetres).</summary>
        public double MetresPerUnit { get; private set; }
        public RsmtSession Session { get { return session; } }
        public RsmtHello Hello { get { return session.Hello; } }
        public bool IsOpen { get { return transport.IsOpen; } }
        /// <summary>Why the connection closed (set once it did).</summary>
        public RsmtIncoming CloseInfo { get; private set; }

        public event Action<RsmtHello> HelloReceived;
        /// <summary>Every message after hello (frames included), poses already in Unity axes.</summary>
        public event Action<RsmtMessage> MessageReceived;
        public event Action<RsmtMessage> ErrorReceived;
        public event Action<int, string> Closed;

        public RsmtStreamClient(IRsmtTransport transport, double bufferDelaySeconds = 0.1)
        {
            this.transport = transport;
            BufferDelay = bufferDelaySeconds;
            MetresPerUnit = 0.01;
        }

        /// <summary>ws(s)://host/v1/stream?encoding=... from an http(s) base URL.</summary>
        public static Uri StreamUri(string baseUrl, bool binary, string token = null)
        {
            string url = baseUrl.TrimEnd('/');
            if (url.StartsWith("https://", StringComparison.OrdinalIgnoreCase)) url = "wss://" + url.Substring(8);
            else if (url.StartsWith("http://", StringComparison.OrdinalIgnoreCase)) url = "ws://" + url.Substring(7);
            if (!url.EndsWith("/v1/stream", StringComparison.Ordinal)) url += "/v1/stream";
            url += "?encoding=" + (binary ? "binary" : "json");
            if (!string.IsNullOrEmpty(token)) url += "&token=" + Uri.EscapeDataString(token);
            return new Uri(url);
        }

        public Task ConnectAsync(string baseUrl, string apiKey, bool binary, CancellationToken cancel = default(CancellationToken))
        {
            var headers = new Dictionary<string, string>();
            if (!string.IsNullOrEmpty(apiKey)) headers["X-API-Key"] = apiKey;
            return transport.ConnectAsync(StreamUri(baseUrl, binary), headers, cancel);
        }

        /// <summary>
        /// Handle every queued message (at most maxMessages): decode, convert to Unity axes, feed the
        /// jitter buffers, raise events. Call once per frame on the main thread; `now` is the clock
        /// TrySample uses (Unity: Time.realtimeSinceStartupAsDouble).
        /// </summary>
        public int Dispatch(double now, int maxMessages = int.MaxValue)
        {
            int handled = 0;
            RsmtIncoming incoming;
            while (handled < maxMessages && transport.TryReceive(out incoming))
            {
                handled++;
                if (incoming.Closed)
                {
                    CloseInfo = incoming;
                    if (Closed != null) Closed(incoming.CloseStatus, incoming.CloseReason);
                    continue;
                }
                RsmtMessage m = incoming.Text != null ? session.HandleText(incoming.Text)
                                                      : session.HandleBinary(incoming.Binary, incoming.Binary.Length);
                Handle(m, now);
            }
            return handled;
        }

        void Handle(RsmtMessage m, double now)
        {
            switch (m.Kind)
            {
                case RsmtMessageKind.Hello:
                    string why = RsmtCoordinates.CheckModel(session.Hello.Model);
                    if (why != null) throw new RsmtProtocolException("unsupported model conventions: " + why);
                    MetresPerUnit = RsmtCoordinates.MetresPerUnit(session.Hello.Model.Units);
                    if (HelloReceived != null) HelloReceived(session.Hello);
                    return;
                case RsmtMessageKind.Started:
                    Buffer(m.Character).Reset();
                    break;
                case RsmtMessageKind.Frame:
                    m.Frame.Pose = RsmtCoordinates.ModelToUnityPose(m.Frame.Pose, MetresPerUnit);
                    if (m.Frame.Character != null) Buffer(m.Frame.Character).Push(m.Frame, now);
                    break;
                case RsmtMessageKind.End:
                    Buffer(m.Character).MarkEnded();
                    break;
                case RsmtMessageKind.Error:
                    if (ErrorReceived != null) ErrorReceived(m);
                    break;
            }
            if (MessageReceived != null) MessageReceived(m);
        }

        public RsmtJitterBuffer Buffer(string character)
        {
            RsmtJitterBuffer b;
            if (!buffers.TryGetValue(character, out b))
            {
                b = new RsmtJitterBuffer(BufferDelay, session.HasHello ? session.Hello.Model.Fps : 30);
                buffers[character] = b;
            }
            return b;
        }

        /// <summary>The pose of `character` to show at `now`, in Unity axes and metres; false until one is due.</summary>
        public bool TrySample(string character, double now, out RsmtPose pose)
        {
            RsmtJitterBuffer b;
            if (!buffers.TryGetValue(character, out b))
            {
                pose = null;
                return false;
            }
            return b.Sample(now, out pose);
        }

        public string Start(RsmtStartOptions options)
        {
            if (string.IsNullOrEmpty(options.Character)) options.Character = "u" + (++nextId);
            Send(RsmtMessages.Start(options));
            return options.Character;
        }

        public void Retarget(string character, string targetJson, int frames = 0)
        {
            Send(RsmtMessages.Retarget(character, targetJson, frames));
        }

        public void SetStyle(string character, string styleId) { Send(RsmtMessages.Style(character, styleId)); }
        public void Cancel(string character) { Send(RsmtMessages.Cancel(character)); }
        public void Ping(string id) { Send(RsmtMessages.Ping(id)); }

        /// <summary>Send without waiting; a failed send surfaces as the connection closing.</summary>
        public void Send(string text)
        {
            transport.SendAsync(text).ContinueWith(t => { var ignored = t.Exception; }, TaskContinuationOptions.OnlyOnFaulted);
        }

        public void Dispose()
        {
            transport.CloseAsync(1000, "bye").Wait(1000);
            transport.Dispose();
        }
    }
}
