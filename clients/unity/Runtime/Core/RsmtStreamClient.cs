// The engine-independent stream client: a transport, the protocol session, coordinate conversion to Unity
// axes and one jitter buffer per character. Everything except ConnectAsync runs on the thread that calls
// Dispatch (Unity: the main thread, from Update), so event handlers may touch Transforms.
// With Failover on, a lost connection is opened again (in the background, with backoff) and every live
// character resumes from the frames it received last (RsmtFailover): the game sees a stall, not an error.
using System;
using System.Collections.Concurrent;
using System.Collections.Generic;
using System.Threading;
using System.Threading.Tasks;

namespace Rsmt.Link
{
    public sealed class RsmtStreamClient : IDisposable
    {
        readonly IRsmtTransport transport;
        RsmtSession session = new RsmtSession();
        readonly Dictionary<string, RsmtJitterBuffer> buffers = new Dictionary<string, RsmtJitterBuffer>();
        readonly RsmtFailover failover = new RsmtFailover();
        readonly ConcurrentQueue<RsmtMessage> late = new ConcurrentQueue<RsmtMessage>();  // from background tasks
        int nextId;
        Uri uri;
        Dictionary<string, string> headers;
        string baseUrl, apiKey;
        Task<bool> reconnecting;
        RsmtIncoming lost;
        bool resumeOnHello;
        volatile bool disposed;  // read by the reconnection task

        /// <summary>
        /// Resume live characters on a new connection when this one is lost (off by default; set it before
        /// Start). Only characters started with Start (and changed with Retarget / SetStyle / Cancel) resume.
        /// </summary>
        public bool Failover;
        /// <summary>Connection attempts after a loss, BackoffSeconds doubling up to MaxBackoffSeconds between them.</summary>
        public int ReconnectAttempts = 8;
        public double BackoffSeconds = 0.25;
        public double MaxBackoffSeconds = 4;
        /// <summary>The resume state (reconnections that resumed characters: FailoverState.Resumes).</summary>
        public RsmtFailover FailoverState { get { return failover; } }
        /// <summary>True while a lost connection is being opened again.</summary>
        public bool Reconnecting { get { return reconnecting != null; } }

        /// <summary>Seconds frames wait before they play (new characters take it from here).</summary>
        public double BufferDelay;
        /// <summary>Metres per model unit, from hello's skeleton.units (0.01 for centimetres).</summary>
        public double MetresPerUnit { get; private set; }
        public RsmtSession Session { get { return session; } }
        RsmtMotionCutter cuts;
        /// <summary>
        /// What hello's model reads of a motion: cut a whole take with Cuts.Context / Target / Style before sending
        /// it (RsmtCharacter does). Null before hello. A cut style clip raises Cuts.Notice once.
        /// </summary>
        public RsmtMotionCutter Cuts
        {
            get
            {
                if (cuts == null && Hello != null) cuts = new RsmtMotionCutter(RsmtMotionLimits.FromModel(Hello.Model));
                return cuts;
            }
        }
        public RsmtHello Hello { get { return session.Hello; } }
        public bool IsOpen { get { return transport.IsOpen; } }
        /// <summary>Why the connection closed (set once it did).</summary>
        public RsmtIncoming CloseInfo { get; private set; }

        public event Action<RsmtHello> HelloReceived;
        /// <summary>Every message after hello (frames included), poses already in Unity axes.</summary>
        public event Action<RsmtMessage> MessageReceived;
        public event Action<RsmtMessage> ErrorReceived;
        public event Action<int, string> Closed;
        /// <summary>The connection was lost and Failover is reconnecting (close status, reason).</summary>
        public event Action<int, string> ConnectionLost;

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
            headers = new Dictionary<string, string>();
            if (!string.IsNullOrEmpty(apiKey)) headers["X-API-Key"] = apiKey;
            this.baseUrl = baseUrl;
            this.apiKey = apiKey;
            uri = StreamUri(baseUrl, binary);
            return transport.ConnectAsync(uri, headers, cancel);
        }

        /// <summary>POST /v1/styles on the server this client connects to; with Failover the clip is kept and
        /// registered again when a new connection answers unknown_style for it.</summary>
        public async Task<RsmtStyleInfo> RegisterStyleAsync(string bvhText, string name)
        {
            if (baseUrl == null) throw new InvalidOperationException("ConnectAsync first");
            using (var http = new RsmtHttpClient(baseUrl, apiKey))
            {
                if (Hello != null) bvhText = Cuts.Style(bvhText);  // else the HTTP client asks for the model and cuts
                var info = await http.RegisterStyleAsync(bvhText, name).ConfigureAwait(false);
                RememberStyle(info.StyleId, bvhText, name);
                return info;
            }
        }

        /// <summary>Hold the clip of a style registered elsewhere, to register it again on unknown_style.</summary>
        public void RememberStyle(string styleId, string bvhText, string name)
        {
            lock (failover) failover.RememberStyle(styleId, bvhText, name);
        }

        /// <summary>
        /// Handle every queued message (at most maxMessages): decode, convert to Unity axes, feed the
        /// jitter buffers, raise events. Call once per frame on the main thread; `now` is the clock
        /// TrySample uses (Unity: Time.realtimeSinceStartupAsDouble).
        /// </summary>
        public int Dispatch(double now, int maxMessages = int.MaxValue)
        {
            int handled = 0;
            RsmtMessage pending;
            while (late.TryDequeue(out pending))
            {
                handled++;
                if (pending.Kind == RsmtMessageKind.Error && ErrorReceived != null) ErrorReceived(pending);
                if (MessageReceived != null) MessageReceived(pending);
            }
            if (reconnecting != null && reconnecting.IsCompleted)
            {
                bool connected = reconnecting.Status == TaskStatus.RanToCompletion && reconnecting.Result;
                reconnecting = null;
                if (!connected) EndConnection(lost);  // gave up: the loss surfaces as it would without failover
            }
            RsmtIncoming incoming;
            while (handled < maxMessages && transport.TryReceive(out incoming))
            {
                handled++;
                if (incoming.Closed)
                {
                    if (reconnecting != null)
                    {
                        reconnecting.Wait(5000);  // only a socket that connected reports a close: the task is ending
                        reconnecting = null;
                    }
                    bool live;
                    lock (failover) live = failover.Live;
                    if (Failover && !disposed && RsmtFailover.Resumable(incoming.CloseStatus) && live)
                    {
                        BeginReconnect(incoming);
                        continue;
                    }
                    EndConnection(incoming);
                    continue;
                }
                RsmtMessage m = incoming.Text != null ? session.HandleText(incoming.Text)
                                                      : session.HandleBinary(incoming.Binary, incoming.Binary.Length);
                Handle(m, now);
            }
            return handled;
        }

        void EndConnection(RsmtIncoming incoming)
        {
            CloseInfo = incoming;
            if (Closed != null) Closed(incoming.CloseStatus, incoming.CloseReason);
        }

        void BeginReconnect(RsmtIncoming incoming)
        {
            lost = incoming;
            session = new RsmtSession();  // the new connection begins with its own hello
            resumeOnHello = true;
            if (ConnectionLost != null) ConnectionLost(incoming.CloseStatus, incoming.CloseReason);
            reconnecting = Task.Run(async () =>
            {
                double wait = BackoffSeconds;
                for (int attempt = 0; attempt < ReconnectAttempts && !disposed; attempt++)
                {
                    await Task.Delay(TimeSpan.FromSeconds(wait)).ConfigureAwait(false);
                    wait = Math.Min(MaxBackoffSeconds, wait * 2);
                    try
                    {
                        // A refused handshake (429, 503, a replica still starting) throws: try again.
                        await transport.ConnectAsync(uri, headers, CancellationToken.None).ConfigureAwait(false);
                        return true;
                    }
                    catch (Exception) { }
                }
                return false;
            });
        }

        void Handle(RsmtMessage m, double now)
        {
            RsmtFailoverAction action = null;
            if (Failover && m.Kind != RsmtMessageKind.Hello)
            {
                lock (failover) action = failover.Received(m);  // renumbers resumed frames (model axes)
            }
            switch (m.Kind)
            {
                case RsmtMessageKind.Hello:
                    string why = RsmtCoordinates.CheckModel(session.Hello.Model);
                    if (why != null) throw new RsmtProtocolException("unsupported model conventions: " + why);
                    MetresPerUnit = RsmtCoordinates.MetresPerUnit(session.Hello.Model.Units);
                    List<string> resume = null;
                    lock (failover)
                    {
                        failover.SetModel(session.Hello.Model);
                        if (resumeOnHello && Failover) resume = failover.ResumeMessages();
                    }
                    resumeOnHello = false;
                    if (resume != null) foreach (var text in resume) Send(text);
                    if (HelloReceived != null) HelloReceived(session.Hello);
                    return;
                case RsmtMessageKind.Started:
                    if (!m.Resumed) Buffer(m.Character).Reset();  // a resumed character plays on
                    break;
                case RsmtMessageKind.Frame:
                    m.Frame.Pose = RsmtCoordinates.ModelToUnityPose(m.Frame.Pose, MetresPerUnit);
                    if (m.Frame.Character != null) Buffer(m.Frame.Character).Push(m.Frame, now);
                    break;
                case RsmtMessageKind.End:
                    Buffer(m.Character).MarkEnded();
                    break;
                case RsmtMessageKind.Error:
                    if (action != null && !action.Deliver)
                    {
                        if (action.RegisterStyleId == null) Send(action.Resend);  // a resume sent again as it was refused
                        else Reregister(m.Character, action.RegisterStyleId, action.Resend);
                        return;
                    }
                    if (Failover && m.Code == "unknown_style")
                        m.Text += " (RsmtStreamClient holds no clip for this style to register it again: register it with"
                                  + " RegisterStyleAsync, or call RememberStyle)";
                    if (ErrorReceived != null) ErrorReceived(m);
                    break;
            }
            if (MessageReceived != null) MessageReceived(m);
        }

        /// <summary>unknown_style on a new connection: POST the clip again (same clip, same id), then resend.</summary>
        void Reregister(string character, string styleId, string resend)
        {
            RsmtFailover.StyleClip clip;
            lock (failover) clip = failover.Style(styleId);
            Task.Run(async () =>
            {
                try
                {
                    using (var http = new RsmtHttpClient(baseUrl, apiKey))
                        await http.RegisterStyleAsync(clip.Bvh, clip.Name).ConfigureAwait(false);
                    await transport.SendAsync(resend).ConfigureAwait(false);
                }
                catch (Exception e)
                {
                    lock (failover) failover.Forget(character);
                    late.Enqueue(new RsmtMessage
                    {
                        Kind = RsmtMessageKind.Error, Type = "error", Character = character, Code = "unknown_style",
                        Text = "registering style " + styleId + " again failed: " + e.Message,
                    });
                }
            });
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
            string text = RsmtMessages.Start(options);
            if (Failover) lock (failover) failover.SentStart(options, text);
            SendLive(text);
            return options.Character;
        }

        public void Retarget(string character, string targetJson, int frames = 0)
        {
            if (Failover) lock (failover) failover.SentRetarget(character, targetJson, frames);
            SendLive(RsmtMessages.Retarget(character, targetJson, frames));
        }

        public void SetStyle(string character, string styleId)
        {
            string text = RsmtMessages.Style(character, styleId);
            if (Failover) lock (failover) failover.SentStyle(character, styleId, text);
            SendLive(text);
        }

        public void Cancel(string character)
        {
            if (Failover) lock (failover) failover.SentCancel(character);
            SendLive(RsmtMessages.Cancel(character));
        }

        /// <summary>While reconnecting, what was sent is in the resume state and goes out with the resume.</summary>
        void SendLive(string text)
        {
            if (Failover && (reconnecting != null || resumeOnHello)) return;
            Send(text);
        }

        public void Ping(string id) { Send(RsmtMessages.Ping(id)); }

        /// <summary>Send without waiting; a failed send surfaces as the connection closing.</summary>
        public void Send(string text)
        {
            transport.SendAsync(text).ContinueWith(t => { var ignored = t.Exception; }, TaskContinuationOptions.OnlyOnFaulted);
        }

        public void Dispose()
        {
            disposed = true;
            transport.CloseAsync(1000, "bye").Wait(1000);
            transport.Dispose();
        }
    }
}
