%% @doc Public API of the WoT Avatar: a W3C Web of Things Thing (its Thing
%% Description, TD 1.1, and the TD's HTTP forms) embodied as an EVATAR
%% Avatar. `describe/2' is the pure reading of a TD; `start/1' and
%% `keep/1' run the process that fetches the TD, joins a pairing and
%% carries the VA's requests to the Thing. docs/wot.md section 6 is the
%% guide; every other wot_avatar_* module is internal.
-module(wot_avatar).

-export([describe/2, limits/0]).
-export([start/1, start_link/1, stop/1, await_ready/2, keep/1, unkeep/1, kept/0, find/1,
         check_opts/1, problems/1, status/1, description/1]).

-export_type([opts/0, describe_opts/0, problem/0, avatar/0]).

-type avatar() :: pid().
-type describe_opts() :: #{entity_id := binary(), component => binary(), room => binary(),
                           api_name => binary(), poll_ms => non_neg_integer(),
                           source_url => binary(), allowed_hosts => [binary()],
                           max_size => pos_integer(), max_affordances => pos_integer()}.
%% The process's options: `td', the TD's http(s) URL or `{file, Path}';
%% `evatar', where to join (as mqtt_avatar's); `thing_credentials' for a Thing
%% whose forms ask for basic (`username', `password') or bearer (`token')
%% security. Times in ms: `request_timeout' (4000: an HTTP request of a
%% VA's request, the TD's GET, a polled read), `longpoll_ms' (60000: a
%% long-poll that long without news is made again), `retry_max_ms' (30000:
%% the longest delay before fetching the TD again once the Thing is away).
%% `max_body' (65536 bytes): the longest answer or SSE event read.
%% `restart': the keeper's back-off (restart_backoff).
-type opts() :: #{entity_id := binary(),
                  td := binary() | {file, file:filename()},
                  evatar := #{endpoints := [agent_bridge_client:endpoint()], pairing := binary(),
                              credential => binary()},
                  component => binary(), room => binary(), api_name => binary(),
                  poll_ms => non_neg_integer(), allowed_hosts => [binary()],
                  max_size => pos_integer(), max_affordances => pos_integer(),
                  thing_credentials => #{username => binary(), password => binary(), token => binary()},
                  request_timeout => pos_integer(), longpoll_ms => pos_integer(),
                  retry_max_ms => pos_integer(), max_body => pos_integer(),
                  restart => restart_backoff:opts()}.
%% Every problem has `what' (an atom from a fixed set) and `message' (a
%% sentence); most have `affordance' (the TD's name of it, made printable)
%% or `stream'; those met while running have `time' (ms since 1970).
-type problem() :: wot_avatar_td:problem().

-define(CALL_TIMEOUT, 15000).
-define(KEYS, [entity_id, td, evatar, component, room, api_name, poll_ms, allowed_hosts, max_size,
               max_affordances, thing_credentials, request_timeout, longpoll_ms, retry_max_ms, max_body,
               restart]).
-define(MAX_BODY_LIMIT, 16777216).

%% @doc The BIL description a TD text gives its Avatar, the routes of its
%% services and streams to the Thing's forms, and the problems of what was
%% left out; `{error, Problems}' for a text that is no TD (not JSON, over
%% the limits, no title or security).
-spec describe(binary(), describe_opts()) ->
          {ok, bil:description(), wot_avatar_generate:routes(), [problem()]} | {error, [problem()]}.
describe(Text, Opts) ->
    case wot_avatar_td:read(Text, maps:with([source_url, allowed_hosts, max_size, max_affordances], Opts)) of
        {ok, Thing, P1} ->
            case wot_avatar_generate:description(
                   Thing, maps:with([entity_id, component, room, api_name, poll_ms], Opts)) of
                {ok, D, Routes, P2} -> {ok, D, Routes, P1 ++ P2};
                {error, P2} -> {error, P1 ++ P2}
            end;
        {error, _} = Error ->
            Error
    end.

%% @doc The limits on a TD (defaults, and the largest max_size) and the
%% default polling interval.
-spec limits() -> #{atom() => pos_integer()}.
limits() ->
    (wot_avatar_td:limits())#{poll_ms => wot_avatar_generate:default_poll_ms()}.

%% ---------------------------------------------------------------------------
%% Running a WoT Avatar
%% ---------------------------------------------------------------------------

%% @doc Starts a WoT Avatar under the application's supervisor (temporary:
%% not restarted). Returns at once; `await_ready/2' waits until it joined.
-spec start(opts()) -> {ok, avatar()} | {error, [problem()] | term()}.
start(Opts) ->
    case check_opts(Opts) of
        ok -> wot_avatar_sup:start_child(Opts);
        {error, _} = Error -> Error
    end.

%% @doc Like `start/1', linked to the caller and outside the supervisor.
-spec start_link(opts()) -> {ok, avatar()} | {error, [problem()] | term()}.
start_link(Opts) ->
    case check_opts(Opts) of
        ok -> wot_avatar_fsm:start_link(maps:remove(restart, Opts));
        {error, _} = Error -> Error
    end.

%% @doc Keeps a WoT Avatar running: when it exits it is started again
%% after a delay from restart_backoff (1 s doubling to 60 s; `restart'
%% changes it). One per entity id; `unkeep/1' ends it. The node
%% configuration file's `wot_avatars' are kept so (the `avatars'
%% application environment).
-spec keep(opts()) -> {ok, pid()} | {error, already_kept | [problem()] | term()}.
keep(Opts) ->
    case check_opts(Opts) of
        ok -> wot_avatar_sup:keep(Opts);
        {error, _} = Error -> Error
    end.

%% @doc Stops a kept Avatar (Bye) and forgets it.
-spec unkeep(binary()) -> ok | {error, not_found}.
unkeep(EntityId) ->
    wot_avatar_sup:unkeep(EntityId).

%% @doc The kept Avatars: entity id, `running' or `waiting', the Avatar's
%% pid while running, starts, short runs in a row, the next delay.
-spec kept() -> [wot_avatar_keeper:status()].
kept() ->
    [wot_avatar_keeper:status(K) || {_, K} <- wot_avatar_sup:keepers()].

%% @doc The running Avatar of a kept entity id.
-spec find(binary()) -> {ok, avatar()} | {error, not_found | waiting}.
find(EntityId) ->
    case [S || #{entity_id := E} = S <- kept(), E =:= EntityId] of
        [#{avatar := Pid}] when is_pid(Pid) -> {ok, Pid};
        [_] -> {error, waiting};
        [] -> {error, not_found}
    end.

%% @doc Leaves EVATAR (Bye), cancels what is in flight, stops.
-spec stop(avatar()) -> ok.
stop(Avatar) ->
    gen_statem:call(Avatar, stop, ?CALL_TIMEOUT).

%% @doc Waits until the Avatar has fetched its TD and joined.
-spec await_ready(avatar(), timeout()) -> ok | {error, timeout}.
await_ready(Avatar, Timeout) ->
    try gen_statem:call(Avatar, await_ready, Timeout)
    catch exit:{timeout, _} -> {error, timeout}
    end.

%% @doc The problems of the TD last read (what describe/2 returned) and,
%% oldest first, the last 100 met while running (the TD or the Thing
%% unreachable, EVATAR's errors, a stream failing).
-spec problems(avatar()) -> [problem()].
problems(Avatar) ->
    gen_statem:call(Avatar, problems, ?CALL_TIMEOUT).

%% @doc `state' (fetching, joined, away), `thing' and `evatar' (up/down),
%% `td', `component', `streams', `pending' requests, `last_values'.
-spec status(avatar()) -> map().
status(Avatar) ->
    gen_statem:call(Avatar, status, ?CALL_TIMEOUT).

%% @doc The description sent to EVATAR (undefined before the TD is read).
-spec description(avatar()) -> bil:description() | undefined.
description(Avatar) ->
    gen_statem:call(Avatar, description, ?CALL_TIMEOUT).

%% @doc Checks options as `start/1' does, every mistake listed.
-spec check_opts(term()) -> ok | {error, [problem()]}.
check_opts(Opts) when is_map(Opts) ->
    Unknown = [bad("unknown key ~0tp (known: ~0tp)", [K, ?KEYS]) || K <- maps:keys(Opts),
                                                                    not lists:member(K, ?KEYS)],
    Checks = [{entity_id, true, fun nonempty/1, "a non-empty binary"},
              {td, true, fun td/1, "an http(s) URL (a binary) or {file, Path}"},
              {evatar, true, fun evatar/1, "#{endpoints => [{Host, Port}], pairing => Binary, "
                                           "credential => Binary}"},
              {component, false, fun nonempty/1, "a non-empty binary"},
              {room, false, fun nonempty/1, "a non-empty binary"},
              {api_name, false, fun nonempty/1, "a non-empty binary"},
              {poll_ms, false, fun(V) -> is_integer(V) andalso V >= 0 end, "a non-negative integer (ms)"},
              {allowed_hosts, false, fun(V) -> is_list(V) andalso lists:all(fun nonempty/1, V) end,
               "a list of binaries, \"host\" or \"host:port\""},
              {max_size, false, fun(V) -> pos(V) andalso V =< maps:get(size_limit, limits()) end,
               "a positive integer, at most " ++ integer_to_list(maps:get(size_limit, limits()))},
              {max_affordances, false, fun pos/1, "a positive integer"},
              {thing_credentials, false, fun credentials/1, "#{username, password} or #{token}, binaries"},
              {request_timeout, false, fun pos/1, "a positive integer (ms)"},
              {longpoll_ms, false, fun pos/1, "a positive integer (ms)"},
              {retry_max_ms, false, fun(V) -> pos(V) andalso V >= 500 end, "an integer of at least 500 (ms)"},
              {max_body, false, fun(V) -> pos(V) andalso V =< ?MAX_BODY_LIMIT end,
               "a positive integer, at most " ++ integer_to_list(?MAX_BODY_LIMIT)}],
    Wrong = [case maps:find(K, Opts) of
                 error when Required -> [bad("~ts is required: ~ts", [K, What], K)];
                 error -> [];
                 {ok, V} -> case Check(V) of
                                true -> [];
                                false -> [bad("~ts must be ~ts", [K, What], K)]
                            end
             end || {K, Required, Check, What} <- Checks],
    Restart = case restart_backoff:check(maps:get(restart, Opts, #{})) of
                  ok -> [];
                  {error, M} -> [#{what => bad_options, key => restart, message => M}]
              end,
    case Unknown ++ lists:append(Wrong) ++ Restart of
        [] -> ok;
        Problems -> {error, Problems}
    end;
check_opts(_) ->
    {error, [bad("the options must be a map", [])]}.

nonempty(V) -> is_binary(V) andalso V =/= <<>>.

pos(V) -> is_integer(V) andalso V > 0.

td({file, F}) -> io_lib:char_list(F) orelse (is_binary(F) andalso F =/= <<>>);
td(<<"http://", _/binary>>) -> true;
td(<<"https://", _/binary>>) -> true;
td(_) -> false.

evatar(#{endpoints := [_ | _] = Es, pairing := P} = E) ->
    nonempty(P) andalso lists:all(fun({_, Port}) -> is_integer(Port); (_) -> false end, Es)
        andalso is_binary(maps:get(credential, E, <<>>));
evatar(_) -> false.

credentials(#{token := T} = C) when map_size(C) =:= 1 -> is_binary(T);
credentials(#{username := U, password := P} = C) when map_size(C) =:= 2 -> is_binary(U) andalso is_binary(P);
credentials(_) -> false.

bad(Format, Args) ->
    #{what => bad_options, message => iolist_to_binary(io_lib:format(Format, Args))}.

bad(Format, Args, Key) ->
    (bad(Format, Args))#{key => Key}.
