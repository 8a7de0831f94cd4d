// The WebSocket transport behind RsmtStreamClient. IRsmtTransport is the seam for other transports:
// ClientWebSocketTransport (System.Net.WebSockets) works in the Editor and on desktop, mobile and
// console players; WebGL has no sockets, so a WebGL build plugs in a transport over a .jslib bridge
// (see README, "WebGL").
using System;
using System.Collections.Concurrent;
using System.Collections.Generic;
using System.IO;
using System.Net.WebSockets;
using System.Text;
using System.Threading;
using System.Threading.Tasks;

namespace Rsmt.Link
{
    /// <summary>One whole message from the server (text or binary), or the end of the connection.</summary>
    public sealed class RsmtIncoming
    {
        public string Text;        // a text message
        public byte[] Binary;      // a binary message
        public bool Closed;        // the connection ended: CloseStatus and CloseReason say why
        public int CloseStatus;
        public string CloseReason;
    }

    public interface IRsmtTransport : IDisposable
    {
        /// <summary>Open the connection; headers go on the handshake (browsers cannot send them: use ?token=).
        /// Called again after the connection closed when RsmtStreamClient.Failover reconnects.</summary>
        Task ConnectAsync(Uri uri, IDictionary<string, string> headers, CancellationToken cancel);
        /// <summary>Queue one text message; sends happen in order.</summary>
        Task SendAsync(string text);
        /// <summary>Next whole message received, if any. Never blocks; call it from the main thread.</summary>
        bool TryReceive(out RsmtIncoming message);
        bool IsOpen { get; }
        Task CloseAsync(int status, string reason);
    }

    /// <summary>
    /// System.Net.WebSockets.ClientWebSocket with a background receive loop: it joins fragments
    /// (EndOfMessage) into whole messages and queues them; the main thread takes them with TryReceive.
    /// When more than MaxQueued messages wait (the main thread stopped dispatching), it stops reading, so
    /// TCP pushes back and the server closes the connection with 1008 rather than memory growing.
    /// </summary>
    public sealed class ClientWebSocketTransport : IRsmtTransport
    {
        readonly ConcurrentQueue<RsmtIncoming> inbox = new ConcurrentQueue<RsmtIncoming>();
        readonly SemaphoreSlim sendLock = new SemaphoreSlim(1, 1);
        readonly CancellationTokenSource stop = new CancellationTokenSource();
        ClientWebSocket socket;
        Task receiveTask;

        public int MaxMessageBytes = 1 << 20;
        public int MaxQueued = 4096;

        public bool IsOpen { get { return socket != null && socket.State == WebSocketState.Open; } }

        public async Task ConnectAsync(Uri uri, IDictionary<string, string> headers, CancellationToken cancel)
        {
            if (receiveTask != null) await receiveTask.ConfigureAwait(false);  // a reconnection: the old loop has ended
            if (socket != null) socket.Dispose();
            socket = new ClientWebSocket();
            if (headers != null)
            {
                foreach (var h in headers) socket.Options.SetRequestHeader(h.Key, h.Value);
            }
            await socket.ConnectAsync(uri, cancel).ConfigureAwait(false);
            receiveTask = Task.Run(() => ReceiveLoop());
        }

        async Task ReceiveLoop()
        {
            var buffer = new byte[16 * 1024];
            var message = new MemoryStream();
            var close = new RsmtIncoming { Closed = true, CloseStatus = 1006, CloseReason = "connection lost" };
            try
            {
                while (!stop.IsCancellationRequested)
                {
                    while (inbox.Count > MaxQueued && !stop.IsCancellationRequested)
                        await Task.Delay(10).ConfigureAwait(false);
                    var r = await socket.ReceiveAsync(new ArraySegment<byte>(buffer), stop.Token).ConfigureAwait(false);
                    if (r.MessageType == WebSocketMessageType.Close)
                    {
                        close.CloseStatus = r.CloseStatus.HasValue ? (int)r.CloseStatus.Value : 1005;
                        close.CloseReason = r.CloseStatusDescription ?? "";
                        try
                        {
                            await socket.CloseOutputAsync(WebSocketCloseStatus.NormalClosure, "", CancellationToken.None).ConfigureAwait(false);
                        }
                        catch (Exception) { }
                        break;
                    }
                    if (message.Length + r.Count > MaxMessageBytes)
                    {
                        close.CloseStatus = 1009;
                        close.CloseReason = "message over " + MaxMessageBytes + " bytes";
                        await socket.CloseAsync(WebSocketCloseStatus.MessageTooBig, "too big", CancellationToken.None).ConfigureAwait(false);
                        break;
                    }
                    message.Write(buffer, 0, r.Count);
                    if (!r.EndOfMessage) continue;
                    var bytes = message.ToArray();
                    message.SetLength(0);
                    inbox.Enqueue(r.MessageType == WebSocketMessageType.Text
                        ? new RsmtIncoming { Text = Encoding.UTF8.GetString(bytes) }
                        : new RsmtIncoming { Binary = bytes });
                }
            }
            catch (Exception e)
            {
                if (!stop.IsCancellationRequested) close.CloseReason = e.Message;
                else close.CloseReason = "closed by the client";
            }
            inbox.Enqueue(close);
        }

        public async Task SendAsync(string text)
        {
            var bytes = Encoding.UTF8.GetBytes(text);
            await sendLock.WaitAsync().ConfigureAwait(false);
            try
            {
                await socket.SendAsync(new ArraySegment<byte>(bytes), WebSocketMessageType.Text, true, stop.Token).ConfigureAwait(false);
            }
            finally
            {
                sendLock.Release();
            }
        }

        public bool TryReceive(out RsmtIncoming message)
        {
            return inbox.TryDequeue(out message);
        }

        public async Task CloseAsync(int status, string reason)
        {
            if (IsOpen)
            {
                try
                {
                    await socket.CloseOutputAsync((WebSocketCloseStatus)status, reason, CancellationToken.None).ConfigureAwait(false);
                }
                catch (Exception) { }
            }
        }

        public void Dispose()
        {
            stop.Cancel();
            if (receiveTask != null) receiveTask.Wait(1000);
            if (socket != null) socket.Dispose();
        }
    }
}
