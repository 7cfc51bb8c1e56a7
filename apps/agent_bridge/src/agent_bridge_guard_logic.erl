%% @doc Internal. The pure decisions of a listener's guard
%% (agent_bridge_guard): which new connection is admitted (connections per
%% listener, handshakes per source address per second, lockout after failed
%% handshakes), how long the refusal of a failed handshake is delayed, and
%% which refusals are logged at once or summed up (docs/protocol.md,
%% section 7). Memory is bounded: at most `max_addresses' addresses are
%% tracked, the others share one `overflow' entry; idle entries expire.
-module(agent_bridge_guard_logic).

-export([default_config/0, config/1, new/1, key/1, admit/3, opened/1, closed/1, failed/3,
         locked/3, expire/2, refused/4, flush/1, size/1]).

-export_type([config/0, state/0, key/0, refusal/0, effect/0]).

%% max_connections: sockets held at once by the listener's connections;
%% rate: handshakes (accepted sockets) per second per address, and burst
%% the most at once; failure_delay doubles with each failed handshake of
%% an address within failure_window, up to max_failure_delay; the
%% max_failures-th failure within failure_window locks the address out for
%% lockout ms; max_addresses bounds the table; summary_interval is how
%% often repeated refusals are summed up in one log line.
-type config() :: #{max_connections := pos_integer() | infinity,
                    rate := pos_integer() | infinity,
                    burst := pos_integer(),
                    failure_delay := non_neg_integer(),
                    max_failure_delay := non_neg_integer(),
                    max_failures := pos_integer(),
                    failure_window := pos_integer(),
                    lockout := non_neg_integer(),
                    max_addresses := pos_integer(),
                    summary_interval := pos_integer(),
                    max_summaries := pos_integer()}.

%% An IPv4 address, an IPv6 /64 (one host usually has a whole /64), the
%% shared entry of addresses beyond max_addresses, or a non-IP peer.
-type key() :: inet:ip4_address() | {v6, non_neg_integer()} | overflow | local.

-type refusal() :: binary().

%% A log line to write: one at the first refusal of an (address, reason)
%% in an interval, one summing up the others at the interval's end.
-type effect() :: {log, key(), refusal(), Count :: pos_integer(), first | summary}.

-record(e, {tokens :: float(),
            at :: integer(),
            failures = 0 :: non_neg_integer(),
            window_start = 0 :: integer(),
            locked_until = 0 :: integer()}).

-record(g, {config :: config(),
            conns = 0 :: non_neg_integer(),
            entries = #{} :: #{key() => #e{}},
            %% {Key, Reason} => refusals not logged yet in this interval
            summaries = #{} :: #{{key(), refusal()} => non_neg_integer()}}).

-opaque state() :: #g{}.

%% @doc The defaults of every key (docs/protocol.md, section 7).
-spec default_config() -> config().
default_config() ->
    #{max_connections => 256,
      rate => 20,
      burst => 100,
      failure_delay => 200,
      max_failure_delay => 5000,
      max_failures => 10,
      failure_window => 60000,
      lockout => 300000,
      max_addresses => 10000,
      summary_interval => 10000,
      max_summaries => 256}.

%% @doc A listener's configuration: its `max_connections' and its
%% `handshake' map over the defaults.
-spec config(map()) -> config().
config(ListenerOpts) ->
    Handshake = maps:get(handshake, ListenerOpts, #{}),
    Base = maps:merge(default_config(), maps:with(maps:keys(default_config()), Handshake)),
    case ListenerOpts of
        #{max_connections := Max} -> Base#{max_connections => Max};
        #{} -> Base
    end.

-spec new(config()) -> state().
new(Config) -> #g{config = Config}.

%% @doc The table key of a peer address.
-spec key(inet:ip_address() | term()) -> key().
key({_, _, _, _} = Ip4) -> Ip4;
key({A, B, C, D, _, _, _, _}) -> {v6, (A bsl 48) bor (B bsl 32) bor (C bsl 16) bor D};
key(_) -> local.

%% @doc Whether a new socket from Key is admitted at time Now (ms). An
%% admitted socket counts against max_connections until closed/1.
-spec admit(key(), integer(), state()) ->
          {ok | {refuse, refusal(), LockedForMs :: non_neg_integer()}, state()}.
admit(_Key, _Now, #g{config = #{max_connections := Max}, conns = N} = G)
  when Max =/= infinity, N >= Max ->
    {{refuse, <<"TooManyConnections">>, 0}, G};
admit(Key0, Now, #g{config = Config} = G) ->
    {Key, E} = entry(Key0, Now, G),
    case E of
        #e{locked_until = Until} when Until > Now ->
            {{refuse, <<"LockedOut">>, Until - Now}, put_entry(Key, E, G)};
        _ ->
            E1 = refill(E, Now, Config),
            case E1#e.tokens >= 1 of
                true ->
                    {ok, opened(put_entry(Key, E1#e{tokens = E1#e.tokens - 1}, G))};
                false ->
                    {{refuse, <<"RateLimited">>, 0}, put_entry(Key, E1, G)}
            end
    end.

%% @doc One more socket held (admitted elsewhere).
-spec opened(state()) -> state().
opened(#g{conns = N} = G) -> G#g{conns = N + 1}.

%% @doc An admitted socket was closed.
-spec closed(state()) -> state().
closed(#g{conns = N} = G) -> G#g{conns = max(0, N - 1)}.

%% @doc A failed handshake (a wrong credential) from Key: how long to wait
%% before the Refused, and for how long the address is locked out (0: not
%% locked; the Refused is then LockedOut, not BadCredential, so a lockout
%% hides every verdict, even of handshakes already under way), and
%% whether this failure started the lockout. Failures of an address
%% already locked out are not counted.
-spec failed(key(), integer(), state()) ->
          {Delay :: non_neg_integer(), LockedMs :: non_neg_integer(), New :: boolean(),
           state()}.
failed(Key0, Now, #g{config = Config} = G) ->
    #{failure_delay := Base, max_failure_delay := MaxDelay, max_failures := MaxFailures,
      failure_window := Window, lockout := Lockout} = Config,
    case entry(Key0, Now, G) of
        {_, #e{locked_until = Until}} when Until > Now ->
            {MaxDelay, Until - Now, false, G};
        {Key, E} ->
            E1 = case Now - E#e.window_start >= Window of
                     true -> E#e{failures = 1, window_start = Now};
                     false -> E#e{failures = E#e.failures + 1}
                 end,
            Delay = min(MaxDelay, Base bsl min(E1#e.failures - 1, 20)),
            case E1#e.failures >= MaxFailures andalso Lockout > 0 of
                true ->
                    E2 = E1#e{locked_until = Now + Lockout, failures = 0, window_start = Now},
                    {Delay, Lockout, true, put_entry(Key, E2, G)};
                false ->
                    {Delay, 0, false, put_entry(Key, E1, G)}
            end
    end.

%% @doc Whether Key is locked out at Now: the ms left, or 0.
-spec locked(key(), integer(), state()) -> non_neg_integer().
locked(Key, Now, G) ->
    case entry(Key, Now, G) of
        {_, #e{locked_until = Until}} when Until > Now -> Until - Now;
        _ -> 0
    end.

%% @doc Drops the entries with nothing to remember: a full bucket, no
%% failures within the window and no lockout.
-spec expire(integer(), state()) -> state().
expire(Now, #g{config = Config, entries = Entries} = G) ->
    #{failure_window := Window} = Config,
    Keep = fun(_, E) ->
                   E#e.locked_until > Now
                       orelse (E#e.failures > 0 andalso Now - E#e.window_start < Window)
                       orelse (refill(E, Now, Config))#e.tokens < float(maps:get(burst, Config))
           end,
    G#g{entries = maps:filter(Keep, Entries)}.

%% @doc A refusal of Reason to Key: logged at once when it is the first of
%% its kind in this interval, else counted for the summary.
-spec refused(key(), refusal(), integer(), state()) -> {[effect()], state()}.
refused(Key0, Reason, _Now, #g{config = #{max_summaries := Max}, summaries = S} = G) ->
    Key = case maps:is_key({Key0, Reason}, S) orelse map_size(S) < Max of
              true -> Key0;
              false -> overflow
          end,
    case maps:find({Key, Reason}, S) of
        {ok, N} -> {[], G#g{summaries = S#{{Key, Reason} => N + 1}}};
        error -> {[{log, Key, Reason, 1, first}], G#g{summaries = S#{{Key, Reason} => 0}}}
    end.

%% @doc The end of a summary interval: one line per (address, reason) with
%% refusals not logged yet.
-spec flush(state()) -> {[effect()], state()}.
flush(#g{summaries = S} = G) ->
    {[{log, Key, Reason, N, summary} || {{Key, Reason}, N} <- lists:sort(maps:to_list(S)), N > 0],
     G#g{summaries = #{}}}.

%% @doc Addresses tracked and sockets held.
-spec size(state()) -> #{addresses := non_neg_integer(), connections := non_neg_integer()}.
size(#g{entries = E, conns = N}) -> #{addresses => map_size(E), connections => N}.

%% ---------------------------------------------------------------------------

entry(Key, Now, #g{config = Config, entries = Entries}) ->
    case maps:find(Key, Entries) of
        {ok, E} ->
            {Key, E};
        error ->
            Fresh = #e{tokens = float(maps:get(burst, Config)), at = Now},
            case map_size(Entries) < maps:get(max_addresses, Config) of
                true -> {Key, Fresh};
                false -> {overflow, maps:get(overflow, Entries, Fresh)}
            end
    end.

put_entry(Key, E, #g{entries = Entries} = G) -> G#g{entries = Entries#{Key => E}}.

refill(E, _Now, #{rate := infinity, burst := Burst}) ->
    E#e{tokens = float(Burst)};
refill(#e{tokens = T, at = At} = E, Now, #{rate := Rate, burst := Burst}) ->
    E#e{tokens = min(float(Burst), T + (Now - At) * Rate / 1000), at = Now}.
