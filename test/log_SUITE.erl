%% Common Test suite of what a node logs (issue 15, section 5): a refusal,
%% a fencing and a feedback timeout each reach the handler configured by
%% the release's config/sys.config.src as exactly one structured event
%% (a report map with `what'), written as exactly one line. Until this
%% suite, the default handler's filters (OTP's defaults, taken when a
%% configuration names none) dropped every event of the pairings' domain
%% [evatar, pairing].
%%
%% Three EVATAR nodes run as OS processes (evatar_test_cluster) with the logger
%% configuration of config/sys.config.src (its `kernel' section, variables
%% at their defaults), so their `default' handler is the release's, writing
%% to each node's standard output (a file). On every node log_capture keeps
%% what that handler receives. The refusal is a Hello with a wrong
%% credential over a real socket; the fencing, the active's node cut off
%% from the two others by evatar_test_proxy; the feedback timeout, an Avatar that
%% never answers a request.
-module(log_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-compile([export_all, nowarn_export_all]).

-define(TIMING, evatar_test_time:ha_timing()).
-define(WAIT, evatar_test_time:guard()).

suite() -> [{timetrap, evatar_test_time:ms(240000)}].

all() ->
    [dev_config_logs_the_same, refusal, feedback_timeout, fencing].

init_per_suite(Config) ->
    Dist = evatar_test_cluster:ensure_distributed(),
    Dir = ?config(priv_dir, Config),
    File = filename:join(Dir, "logger.config"),
    ok = file:write_file(File, io_lib:format("~tp.~n", [[{kernel, release_kernel_env()}]])),
    {ok, C} = evatar_test_cluster:start(#{dir => Dir, prefix => "lg", evatar => ?TIMING,
                                          modules => [log_capture],
                                          config => File}),
    _ = [ok = evatar_test_cluster:call(C, I, log_capture, install, []) || I <- [1, 2, 3]],
    [{dist, Dist}, {cluster, C}, {dir, Dir} | Config].

end_per_suite(Config) ->
    ok = evatar_test_cluster:stop(?config(cluster, Config)),
    evatar_test_cluster:release_distribution(?config(dist, Config)).

init_per_testcase(Case, Config) ->
    [{pairing, <<"log-", (atom_to_binary(Case))/binary>>} | Config].

end_per_testcase(_Case, Config) ->
    evatar_test_pairing:reset(?config(cluster, Config), ?config(pairing, Config), ?WAIT).

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% config/sys.config (development, rebar3 shell, make demo) configures the
%% logger as the release does.
dev_config_logs_the_same(_Config) ->
    {ok, [Dev]} = file:consult(filename:join([evatar_test_cluster:repo_root(), "config", "sys.config"])),
    {kernel, DevKernel} = lists:keyfind(kernel, 1, Dev),
    ?assertEqual(proplists:get_value(logger, release_kernel_env()),
                 proplists:get_value(logger, DevKernel)).

%% A Hello with a wrong credential over a real socket: the client is
%% refused with BadCredential, and the node logs it once.
refusal(Config) ->
    C = ?config(cluster, Config),
    Id = ?config(pairing, Config),
    ok = evatar_test_pairing:create(C, 1, Id),
    Entity = <<Id/binary, "-intruder">>,
    {Ip, Port} = evatar_test_cluster:endpoint(C, 1),
    {ok, S} = gen_tcp:connect(Ip, Port, [binary, {packet, 4}, {active, false}]),
    ok = gen_tcp:send(S, bil_control:encode(
                           {hello, #{pairing => Id, role => agent, entity_id => Entity,
                                     credential => <<"a guess">>, protocol_version => 1}})),
    {ok, Frame} = gen_tcp:recv(S, 0, ?WAIT),
    {ok, {control, {refused, #{code := <<"BadCredential">>}}}} = bil_control:parse_frame(Frame, #{}),
    {error, closed} = gen_tcp:recv(S, 0, ?WAIT),
    %% The connection has the refusal logged before it closes: once the
    %% client sees the close, everything it logged has been kept.
    Mine = fun(#{msg := {report, R}}) -> lists:member(Entity, maps:values(R));
              (_) -> false
           end,
    [Event] = settled(C, 1, Mine),
    %% The listener's guard writes it (docs/protocol.md section 7.1).
    #{what := handshake_refused, reason := <<"BadCredential">>, count := 1} = report(Event),
    ok = one_line(Event),
    ok = in_node_output(Config, 1, "what: handshake_refused", Entity).

%% A request to an Avatar that never answers: the VA gets EVATAR's Timeout
%% feedback, and the pairing logs the timeout once.
feedback_timeout(Config) ->
    C = ?config(cluster, Config),
    Id = ?config(pairing, Config),
    ok = evatar_test_pairing:create(C, 1, Id, #{feedback_timeout => evatar_test_time:cluster_ms(300)}),
    Ep = [evatar_test_cluster:endpoint(C, 1)],
    Opts = maps:with([agent_credential, avatar_credential], evatar_test_traffic:pairing_opts()),
    {ok, Av} = agent_bridge_client:connect(Ep, #{pairing => Id, role => avatar,
                                                 entity_id => <<Id/binary, "-av">>,
                                                 credential => maps:get(avatar_credential, Opts)}),
    ok = agent_bridge_client:describe(Av, evatar_test_traffic:avatar_description(<<Id/binary, "-av">>)),
    {ok, Va} = agent_bridge_client:connect(Ep, #{pairing => Id, role => agent,
                                                 entity_id => <<Id/binary, "-va">>,
                                                 credential => maps:get(agent_credential, Opts)}),
    ok = agent_bridge_client:describe(Va, evatar_test_traffic:va_description(<<Id/binary, "-va">>)),
    ok = await_bound(Va),
    SigId = <<Id/binary, "-r1">>,
    {ok, #{context := feedback, body := #{category := <<"EVATAR">>, type := <<"Timeout">>}}} =
        agent_bridge_client:request(Va, #{id => SigId, sender => <<"LightEmulator01">>,
                                          receiver => <<"Light01">>,
                                          body => #{category => <<"ACTUATOR">>,
                                                    type => <<"TurnLightOn">>,
                                                    parameters => []}}, ?WAIT),
    %% A call to the pairing returns after the step that timed out, logging
    %% included, is over.
    {ok, _} = evatar_test_cluster:call(C, 1, evatar, ha_status, [Id]),
    Mine = fun(#{msg := {report, #{what := feedback_timeout} = R}}) ->
                   maps:get(signal, R, undefined) =:= SigId;
              (_) -> false
           end,
    [Event] = settled(C, 1, Mine),
    #{what := feedback_timeout, signal := SigId} = report(Event),
    #{pairing := Id} = maps:get(meta, Event),
    ok = one_line(Event),
    ok = agent_bridge_client:close(Va),
    ok = agent_bridge_client:close(Av),
    ok = in_node_output(Config, 1, "what: feedback_timeout", SigId).

%% The active's node is cut off from both others: it loses the majority and
%% fences its pairing, which it logs once; no other node logs a fencing.
fencing(Config) ->
    C = ?config(cluster, Config),
    Id = ?config(pairing, Config),
    ok = evatar_test_pairing:create(C, 1, Id),
    {ok, 1, #{epoch := E0}} = evatar_test_pairing:active(C, Id),
    ok = evatar_test_cluster:isolate(C, 1),
    {ok, _, _} = evatar_test_pairing:await_active(C, Id, fun(I, #{epoch := E}) -> I =/= 1 andalso E > E0 end,
                                                  ?WAIT),
    %% The role is published after the fencing was logged.
    ok = evatar_test_cluster:await(fun() ->
                                  case evatar_test_cluster:call(C, 1, evatar, ha_status, [Id]) of
                                      {ok, #{role := active}} -> false;
                                      {ok, #{}} -> true;
                                      _ -> false
                                  end
                          end, ?WAIT, {fenced, Id}),
    ok = evatar_test_cluster:heal(C, flush),
    ok = evatar_test_cluster:await_formed(C, ?WAIT),
    ok = evatar_test_pairing:await_healthy(C, Id, ?WAIT),
    Fenced = fun(#{msg := {report, #{what := fenced, pairing := P}}}) -> P =:= Id;
                (_) -> false
             end,
    [Event] = settled(C, 1, Fenced),
    #{what := fenced, pairing := Id} = report(Event),
    #{level := warning} = Event,
    ok = one_line(Event),
    ?assertEqual([], settled(C, 2, Fenced)),
    ?assertEqual([], settled(C, 3, Fenced)),
    ok = in_node_output(Config, 1, "what: fenced", Id).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

%% The kernel section of config/sys.config.src, each ${NAME:-default}
%% replaced by its default, as bin/evatar does with no variable set.
release_kernel_env() ->
    Src = filename:join([evatar_test_cluster:repo_root(), "config", "sys.config.src"]),
    {ok, Bin} = file:read_file(Src),
    Filled = re:replace(Bin, "\\$\\{[A-Z_]+:-([^}]*)\\}", "\\1", [global, {return, list}]),
    {ok, Tokens, _} = erl_scan:string(Filled),
    {ok, Terms} = erl_parse:parse_term(Tokens),
    {kernel, Kernel} = lists:keyfind(kernel, 1, Terms),
    Kernel.

%% The events node I kept that satisfy Pred, once it kept a marker logged
%% after them.
settled(C, I, Pred) ->
    Id = erlang:unique_integer([positive]),
    ok = evatar_test_cluster:call(C, I, log_capture, marker, [Id]),
    IsMarker = fun(#{msg := {report, #{what := log_capture_marker, id := M}}}) -> M =:= Id;
                  (_) -> false
               end,
    ok = evatar_test_cluster:await(fun() -> lists:any(IsMarker, events(C, I)) end, ?WAIT,
                                   {marker, I}),
    [E || E <- events(C, I), Pred(E)].

events(C, I) ->
    case evatar_test_cluster:call(C, I, log_capture, events, []) of
        Events when is_list(Events) -> Events
    end.

report(#{msg := {report, Report}}) when is_map(Report) -> Report.

%% The configured formatter made one line of it.
one_line(#{line := Line}) ->
    case binary:split(Line, <<"\n">>, [global]) of
        [Text, <<>>] when Text =/= <<>> -> ok;
        Parts -> {error, {not_one_line, Parts}}
    end.

%% The node's own default handler wrote exactly one line with both
%% strings to its standard output (evatar_test_cluster's NAME.out), by the time a
%% marker logged after it is there too.
in_node_output(Config, I, What, Key) ->
    C = ?config(cluster, Config),
    Out = filename:join(?config(dir, Config),
                        hd(string:split(atom_to_list(evatar_test_cluster:node(C, I)), "@")) ++ ".out"),
    Marker = "marker-" ++ integer_to_list(erlang:unique_integer([positive])),
    ok = evatar_test_cluster:call(C, I, log_capture, marker, [list_to_binary(Marker)]),
    Lines = fun() ->
                    {ok, Bin} = file:read_file(Out),
                    string:split(Bin, "\n", all)
            end,
    ok = evatar_test_cluster:await(fun() -> lists:any(fun(L) -> string:find(L, Marker) =/= nomatch end,
                                                      Lines())
                          end, ?WAIT, {marker_in, Out}),
    case [L || L <- Lines(), string:find(L, What) =/= nomatch,
               string:find(L, Key) =/= nomatch] of
        [_] -> ok;
        Other -> {error, {lines, Out, Other}}
    end.

await_bound(Va) ->
    receive
        {agent_bridge, Va, {binding, #{bound := [_ | _]}}} -> ok;
        {agent_bridge, Va, {binding, _}} -> await_bound(Va)
    after ?WAIT -> {error, not_bound}
    end.
