%% @doc Common Test suite of the dashboard (docs/dashboard.md): the page in
%% a real browser (Debian's chromium, headless, driven by playwright-core
%% from npm) showing a pairing joined by a real VA and a real Avatar over
%% TCP, its graph, an unbound entry with its reason, a request appearing
%% live; the event stream over HTTP with its errors, its filters and its
%% limit; the graph and scenes routes.
-module(evatar_web_dash_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-import(evatar_test_wait, [until/1]).

-export([all/0, groups/0, suite/0, init_per_suite/1, end_per_suite/1,
         init_per_group/2, end_per_group/2]).
-export([page_in_chromium/1, events_stream/1, events_errors/1, events_client_goes/1,
         streams_are_capped/1, graph_route/1, scenes_route/1]).

-define(T, evatar_web_test).
-define(P, <<"dash-home">>).
-define(VA, <<"va-dash">>).
-define(AV, <<"avatar-dash">>).
%% A pairing id and an entity id of 400 characters (the phone-width check).
-define(LONG_P, <<"dash-long-", (binary:copy(<<"p">>, 390))/binary>>).
-define(LONG_AV, <<"avatar-long-", (binary:copy(<<"e">>, 388))/binary>>).

suite() -> [{timetrap, {minutes, 8}}].

all() -> [{group, http}, {group, browser}].

groups() ->
    [{http, [], [events_stream, events_errors, events_client_goes, streams_are_capped,
                 graph_route, scenes_route]},
     {browser, [], [page_in_chromium]}].

init_per_suite(Config) ->
    ?T:start(#{}),
    {ok, _} = application:ensure_all_started(agent_bridge),
    {ok, _} = application:ensure_all_started(avatar_sim),
    {ok, _} = agent_bridge:start_listener(dash, #{port => 0}),
    {ok, Addr} = agent_bridge:address(dash),
    {ok, _} = evatar:create_pairing(?P, #{agent_credential => <<"va-secret">>,
                                          avatar_credential => <<"av-secret">>,
                                          join_timeout => 60000, feedback_timeout => 60000}),
    Av = start_avatar(Addr),
    Va = start_va(Addr),
    [{va, Va}, {avatar, Av} | Config].

end_per_suite(Config) ->
    exit(?config(va, Config), shutdown),
    exit(?config(avatar, Config), shutdown),
    ok = evatar:delete_pairing(?P),
    ok = agent_bridge:stop_listener(dash),
    ?T:stop().

init_per_group(_, Config) -> Config.
end_per_group(_, _Config) -> ok.

%% ---------------------------------------------------------------------------
%% The pairing: a VA with a light switch (bound to the avatar's kitchen
%% light) and a camera wanted in the garden (the avatar's camera is in the
%% hall: ParametersMismatch).
%% ---------------------------------------------------------------------------

entry(Cat, Type, Ps) -> #{category => Cat, type => Type, parameters => Ps}.

description(Id, Type, Components) ->
    #{entity_id => Id, api_name => <<"dashboard test">>, entity_type => Type, context => <<>>,
      components => [#{id => C, services => S, consumes => U} || {C, S, U} <- Components]}.

va_description() ->
    description(?VA, agent,
                [{<<"LightSwitch">>, [entry(<<"ACTUATOR">>, <<"ActionFeedback">>, [])], [entry(<<"ACTUATOR">>, <<"TurnLightOn">>,
                                                [{<<"Room">>, <<"kitchen">>}])]},
                 {<<"GardenEye">>, [entry(<<"SENSOR">>, <<"PhotoTaken">>, [])], [entry(<<"SENSOR">>, <<"TakePhoto">>,
                                              [{<<"Room">>, <<"garden">>}])]}]).

av_description() ->
    description(?AV, avatar,
                [{<<"KitchenLight">>, [entry(<<"ACTUATOR">>, <<"TurnLightOn">>,
                                             [{<<"Room">>, <<"kitchen">>}])], []},
                 {<<"HallCamera">>, [entry(<<"SENSOR">>, <<"TakePhoto">>,
                                           [{<<"Room">>, <<"hall">>}])], []}]).

%% The Avatar: its own process, answering every request with Feedback.
start_avatar(Addr) ->
    Parent = self(),
    Pid = spawn(fun() ->
                        {ok, C} = agent_bridge_client:connect(
                                    [Addr], #{pairing => ?P, role => avatar, entity_id => ?AV,
                                              credential => <<"av-secret">>}),
                        ok = agent_bridge_client:describe(C, av_description()),
                        Parent ! {avatar_up, self()},
                        avatar_loop(C)
                end),
    receive {avatar_up, Pid} -> Pid after evatar_test_time:guard() -> ct:fail(avatar_did_not_join) end.

avatar_loop(C) ->
    receive
        {agent_bridge, C, {signal, #{context := request, id := Id, sender := S, receiver := R}}} ->
            ok = agent_bridge_client:send(C, #{context => feedback, sender => R, receiver => S,
                                               in_reply_to => Id,
                                               body => entry(<<"ACTUATOR">>, <<"ActionFeedback">>,
                                                             [{<<"Done">>, <<"yes">>}])}),
            avatar_loop(C);
        {agent_bridge, C, {closed, _}} ->
            ok;
        {agent_bridge, C, _} ->
            avatar_loop(C)
    end.

%% The VA: its own process too (this one ends with init_per_suite), which
%% sends the light request when asked.
start_va(Addr) ->
    Parent = self(),
    Pid = spawn(fun() ->
                        {ok, C} = agent_bridge_client:connect(
                                    [Addr], #{pairing => ?P, role => agent, entity_id => ?VA,
                                              credential => <<"va-secret">>}),
                        ok = agent_bridge_client:describe(C, va_description()),
                        ok = await_binding(C),
                        Parent ! {va_up, self()},
                        va_loop(C)
                end),
    receive {va_up, Pid} -> Pid after evatar_test_time:guard() -> ct:fail(va_did_not_bind) end.

va_loop(C) ->
    receive
        {request, From} ->
            From ! {requested, agent_bridge_client:send(
                                 C, #{context => request, sender => <<"LightSwitch">>,
                                      receiver => <<"KitchenLight">>,
                                      body => entry(<<"ACTUATOR">>, <<"TurnLightOn">>,
                                                    [{<<"Room">>, <<"kitchen">>}])})},
            va_loop(C);
        {agent_bridge, C, {closed, _}} ->
            ok;
        {agent_bridge, C, _} ->
            va_loop(C)
    end.

await_binding(Va) ->
    receive
        {agent_bridge, Va, {binding, #{bound := [_ | _]}}} -> ok;
        {agent_bridge, Va, {binding, _}} -> await_binding(Va)
    after evatar_test_time:guard() -> ct:fail(no_binding)
    end.

light_request(Va) ->
    Va ! {request, self()},
    receive {requested, Result} -> ok = Result after evatar_test_time:guard() -> ct:fail(va_silent) end.

%% ---------------------------------------------------------------------------
%% An event stream read over a raw socket
%% ---------------------------------------------------------------------------

open_stream(Query) ->
    {ok, S} = gen_tcp:connect({127, 0, 0, 1}, evatar_web:port(), [binary, {active, false}]),
    ok = gen_tcp:send(S, ["GET /api/events?", Query, " HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"]),
    {ok, Head, Rest} = head(S, <<>>),
    {S, Head, Rest}.

%% The response head; the deadline only guards against a hang (the first
%% answer of a node that has just started can take longer than a fixed
%% figure on a loaded machine).
head(S, Acc) ->
    case binary:split(Acc, <<"\r\n\r\n">>) of
        [Head, Rest] -> {ok, Head, Rest};
        [_] ->
            case gen_tcp:recv(S, 0, evatar_test_time:guard()) of
                {ok, More} -> head(S, <<Acc/binary, More/binary>>);
                {error, Why} -> ct:fail({no_head, Why, Acc})
            end
    end.

%% The items of the stream until `Pred' holds for the list so far (the
%% hang guard as deadline).
items(S, Buf, Pred) -> items(S, Buf, Pred, []).

items(S, Buf, Pred, Acc) ->
    {Events, Rest} = split_events(Buf),
    Acc1 = Acc ++ Events,
    case Pred(Acc1) of
        true -> {Acc1, Rest};
        false ->
            case gen_tcp:recv(S, 0, evatar_test_time:guard()) of
                {ok, More} -> items(S, <<Rest/binary, More/binary>>, Pred, Acc1);
                {error, Why} -> ct:fail({stream_ended, Why, Acc1})
            end
    end.

split_events(Buf) ->
    Parts = binary:split(Buf, <<"\n\n">>, [global]),
    {Complete, [Rest]} = lists:split(length(Parts) - 1, Parts),
    {[Item || <<"data: ", Json/binary>> <- Complete,
              {ok, Item} <- [evatar_json:decode(Json)]], Rest}.

has_kind(Kind) -> fun(Is) -> [x || #{<<"kind">> := K} <- Is, K =:= Kind] =/= [] end.


%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% @doc The stream answers text/event-stream, says hello, and carries a
%% request and its feedback as they are routed; a kind filter keeps only
%% what it names.
events_stream(Config) ->
    Open = evatar_web_streams:count(),
    {S, Head, Rest} = open_stream("pairing=" ++ binary_to_list(?P)),
    {match, _} = re:run(Head, "^HTTP/1.1 200"),
    {match, _} = re:run(Head, "(?i)content-type: text/event-stream"),
    {[#{<<"kind">> := <<"hello">>, <<"pairing">> := ?P}], Rest1} =
        items(S, Rest, has_kind(<<"hello">>)),
    {F, _, FRest} = open_stream("pairing=" ++ binary_to_list(?P) ++ "&kind=feedback"),
    {_, FRest1} = items(F, FRest, has_kind(<<"hello">>)),
    light_request(?config(va, Config)),
    {Items, _} = items(S, Rest1, has_kind(<<"feedback">>)),
    [#{<<"from">> := <<"LightSwitch">>, <<"to">> := <<"KitchenLight">>,
       <<"from_entity">> := ?VA, <<"to_entity">> := ?AV, <<"signal">> := Id}] =
        [I || #{<<"kind">> := <<"request">>} = I <- Items],
    [#{<<"in_reply_to">> := Id, <<"from">> := <<"KitchenLight">>}] =
        [I || #{<<"kind">> := <<"feedback">>} = I <- Items],
    {FItems, _} = items(F, FRest1, has_kind(<<"feedback">>)),
    [<<"feedback">>] = [K || #{<<"kind">> := K} <- FItems],
    ok = gen_tcp:close(S),
    ok = gen_tcp:close(F),
    %% Both streams have ended (and left the pairing's watchers) before the
    %% next case counts the watchers: the server sees a close only when it
    %% next runs, later on a loaded machine.
    until(fun() -> evatar_web_streams:count() =:= Open end).

%% @doc A missing pairing, an unknown pairing and an unknown kind are JSON
%% errors naming the field.
events_errors(_Config) ->
    {400, #{<<"error">> := <<"missing_field">>, <<"field">> := <<"pairing">>}} =
        ?T:get("/api/events"),
    {404, #{<<"error">> := <<"not_found">>, <<"field">> := <<"pairing">>}} =
        ?T:get("/api/events?pairing=nobody"),
    {400, #{<<"error">> := <<"bad_value">>, <<"field">> := <<"kind">>}} =
        ?T:get("/api/events?pairing=dash-home&kind=request,teleport").

%% @doc A client that goes ends its stream: its slot and its watcher are
%% freed, and the node goes on serving.
events_client_goes(_Config) ->
    Pid = evatar_registry:whereis_name(?P),
    Before = gen_statem:call(Pid, {inspect, watchers}),
    {S, _, Rest} = open_stream("pairing=" ++ binary_to_list(?P)),
    {_, _} = items(S, Rest, has_kind(<<"hello">>)),
    Open = evatar_web_streams:count(),
    ?assert(Open >= 1),
    ?assertEqual(Before + 1, gen_statem:call(Pid, {inspect, watchers})),
    ok = gen_tcp:close(S),
    until(fun() -> gen_statem:call(Pid, {inspect, watchers}) =:= Before end),
    until(fun() -> evatar_web_streams:count() =:= Open - 1 end),
    {200, _} = ?T:get("/api/cluster").

%% @doc At most half of max_clients streams at once; the next one is a JSON
%% 503 `too_many_streams', and the API still answers.
streams_are_capped(_Config) ->
    Max = evatar_web_streams:max(),
    Open = evatar_web_streams:count(),
    %% The pairing takes 16 watchers at most: spread over pairings.
    Pairings = [begin
                    P = <<"dash-cap-", (integer_to_binary(I))/binary>>,
                    {ok, _} = evatar:create_pairing(P, #{agent_credential => <<"a">>,
                                                         avatar_credential => <<"b">>}),
                    P
                end || I <- lists:seq(1, Max div 16 + 1)],
    Streams = [begin
                   P = lists:nth(I rem length(Pairings) + 1, Pairings),
                   {S, _, R} = open_stream("pairing=" ++ binary_to_list(P)),
                   {_, _} = items(S, R, has_kind(<<"hello">>)),
                   S
               end || _I <- lists:seq(1, Max - Open), I <- [_I]],
    Max = evatar_web_streams:count(),
    {503, #{<<"error">> := <<"too_many_streams">>}} =
        ?T:get("/api/events?pairing=" ++ binary_to_list(hd(Pairings))),
    {200, _} = ?T:get("/api/cluster"),
    [ok = gen_tcp:close(S) || S <- Streams],
    until(fun() -> evatar_web_streams:count() =:= Open end),
    [ok = evatar:delete_pairing(P) || P <- Pairings].

%% @doc The graph route: both entities with their components, the bound
%% light, the unbound camera with ParametersMismatch and the parameter
%% that did not match.
graph_route(_Config) ->
    {200, #{<<"pairing">> := ?P, <<"entities">> := Entities, <<"bound">> := Bound,
            <<"unbound">> := Unbound}} = ?T:get("/api/pairings/dash-home/graph"),
    [?AV, ?VA] = lists:sort([Id || #{<<"id">> := Id, <<"attached">> := true,
                                     <<"registered">> := true} <- Entities]),
    [#{<<"consumer">> := #{<<"component">> := <<"LightSwitch">>},
       <<"provider">> := #{<<"component">> := <<"KitchenLight">>, <<"entity">> := ?AV}}] = Bound,
    [#{<<"consumer">> := #{<<"component">> := <<"GardenEye">>},
       <<"reason">> := <<"ParametersMismatch">>,
       <<"parameters">> := [[<<"Room">>, <<"garden">>]],
       <<"candidates">> := [#{<<"provider">> := #{<<"component">> := <<"HallCamera">>},
                              <<"mismatches">> := [#{<<"name">> := <<"Room">>,
                                                     <<"wanted">> := <<"garden">>,
                                                     <<"offered">> := [<<"hall">>]}]}]}] = Unbound,
    {404, #{<<"error">> := <<"not_found">>, <<"field">> := <<"id">>}} =
        ?T:get("/api/pairings/nobody/graph").

%% @doc The scenes route lists what avatar_sim runs: a home and an arena
%% once started, no more once stopped.
scenes_route(Config) ->
    %% Worlds another suite left running in this node come first.
    {200, #{<<"scenes">> := Before}} = ?T:get("/api/scenes"),
    {Home, Arena} = start_worlds(Config),
    {200, #{<<"scenes">> := After}} = ?T:get("/api/scenes"),
    Sim = fun(Scenes) -> [S || #{<<"source">> := <<"avatar_sim">>} = S <- Scenes] end,
    [#{<<"kind">> := <<"home">>, <<"rooms">> := [_ | _]},
     #{<<"kind">> := <<"arena">>, <<"robots">> := [_, _]}] =
        lists:nthtail(length(Sim(Before)), Sim(After)),
    ok = avatar_sim:stop(Home),
    ok = avatar_sim:stop(Arena),
    {200, #{<<"scenes">> := Again}} = ?T:get("/api/scenes"),
    ?assertEqual(length(Before), length(Again)).

start_worlds(Config) ->
    Spool = filename:join(?config(priv_dir, Config), "spool"),
    {ok, Home} = avatar_sim:start_home(#{people => #{<<"alice">> => <<"kitchen">>,
                                                    <<"bob">> => <<"living">>},
                                         spool => Spool}),
    {ok, Arena} = avatar_sim:start_arena(#{}),
    {Home, Arena}.

%% @doc The page in Debian's chromium: the cluster lists the pairing; its
%% view comes into the window when opened from a table of 200 pairings and
%% shows both entities, the bound edge, the unbound camera with its reason;
%% a request sent by the VA appears in the live tail and flashes its edge;
%% the graph's periodic redraw keeps the edge's count of signals. The
%% simulated home's pairing (evatar_demo_holiday) draws one edge per
%% bound entry, no label under a box; the rooms show their whole device
%% lists; the page fits a 390 px screen with a 400-character pairing id and
%% entity id; the arena shows the names the robot VAs anchored (the robots
%% story, started as `make demo' starts it, with evatar_demo not
%% loaded); axe-core finds nothing serious or critical on any view, and each
%% has a heading level one. Screenshots go to the logs.
page_in_chromium(Config) ->
    Dir = ?config(data_dir, Config),
    Shots = ?config(priv_dir, Config),
    ok = npm_install(Dir),
    {ok, Addr} = agent_bridge:address(dash),
    {Home, Arena} = start_worlds(Config),
    Many = [begin
                P = iolist_to_binary(io_lib:format("dash-many-~3..0b", [I])),
                {ok, _} = evatar:create_pairing(P, #{agent_credential => <<"a">>,
                                                     avatar_credential => <<"b">>}),
                P
            end || I <- lists:seq(1, 200)],
    {ok, _} = evatar:create_pairing(?LONG_P, #{agent_credential => <<"la">>,
                                               avatar_credential => <<"lb">>,
                                               max_id_length => 512, join_timeout => 60000}),
    Long = start_long_avatar(Addr),
    {ok, Holiday} = evatar_demo_holiday:start(
                      #{print => false, spool => filename:join(Shots, "holiday-spool")}),
    Stories = #{holiday => Holiday, arena => Arena},
    try
        Url = evatar_web:url(),
        Node = os:find_executable("node"),
        Port = open_port({spawn_executable, Node},
                         [{args, [filename:join(Dir, "dashboard.mjs"), Url, binary_to_list(?P),
                                  "home", binary_to_list(?LONG_P), binary_to_list(?LONG_AV), Shots]},
                          {cd, Dir}, {line, 16384}, exit_status, stderr_to_stdout]),
        {Result, Stories1} = browser(Port, ?config(va, Config), Stories, []),
        put(stories, Stories1),
        [ct:log("<a href=\"file://~ts\">~ts</a><br><img src=\"file://~ts\" width=\"640\">",
                [F, filename:basename(F), F])
         || F <- [filename:join(Shots, "dashboard.png"), filename:join(Shots, "dashboard-mobile.png")],
            filelib:is_regular(F)],
        ok = Result
    after
        Left = case get(stories) of undefined -> Stories; S -> S end,
        [ok = evatar_demo_holiday:stop(H) || #{holiday := H} <- [Left]],
        [ok = evatar_demo_lego_scenario:stop(R) || #{robots := R} <- [Left]],
        [ok = avatar_sim:stop(A) || #{arena := A} <- [Left]],
        ok = avatar_sim:stop(Home),
        exit(Long, shutdown),
        [ok = evatar:delete_pairing(P) || P <- [?LONG_P | Many]]
    end.

%% An Avatar whose entity id is 400 characters long, in a pairing whose id
%% is too.
start_long_avatar(Addr) ->
    Parent = self(),
    Pid = spawn(fun() ->
                        {ok, C} = agent_bridge_client:connect(
                                    [Addr], #{pairing => ?LONG_P, role => avatar,
                                              entity_id => ?LONG_AV, credential => <<"lb">>}),
                        ok = agent_bridge_client:describe(
                               C, description(?LONG_AV, avatar,
                                              [{<<"KitchenLight">>, [entry(<<"ACTUATOR">>, <<"TurnLightOn">>, [])], []}])),
                        Parent ! {avatar_up, self()},
                        avatar_loop(C)
                end),
    receive {avatar_up, Pid} -> Pid after evatar_test_time:guard() -> ct:fail(long_avatar_did_not_join) end.

%% The script says `ready' when the VA should send its requests, `robots'
%% when it is done with the home and wants the robots story (the holiday
%% and the other arena stopped first: the anchors are drawn on every
%% arena shown).
browser(Port, Va, Stories, Lines) ->
    receive
        {Port, {data, {eol, "ready"}}} ->
            ct:log("browser: ready; the VA sends 20 requests"),
            [light_request(Va) || _ <- lists:seq(1, 20)],
            browser(Port, Va, Stories, ["ready" | Lines]);
        {Port, {data, {eol, "robots"}}} ->
            ct:log("browser: robots; the holiday stops, the robots story starts"),
            #{holiday := H, arena := A} = Stories,
            ok = evatar_demo_holiday:stop(H),
            ok = avatar_sim:stop(A),
            %% As in `make demo': nothing has loaded the application.
            case lists:keymember(evatar_demo, 1, application:which_applications()) of
                false -> _ = application:unload(evatar_demo);
                true -> ok
            end,
            {ok, R} = evatar_demo_lego_scenario:start(#{print => false}),
            browser(Port, Va, #{robots => R}, ["robots" | Lines]);
        {Port, {data, {eol, Line}}} ->
            ct:log("browser: ~ts", [Line]),
            browser(Port, Va, Stories, [Line | Lines]);
        {Port, {data, {noeol, Line}}} ->
            browser(Port, Va, Stories, [Line | Lines]);
        {Port, {exit_status, 0}} ->
            "OK" = hd(Lines),
            {ok, Stories};
        {Port, {exit_status, Status}} ->
            {{error, {browser_test_failed, Status, lists:reverse(Lines)}}, Stories}
    after evatar_test_time:ms(180000) ->
            {{error, {browser_silent, lists:reverse(Lines)}}, Stories}
    end.

%% playwright-core and axe-core from npm, at the versions package-lock.json
%% pins, installed next to the script when missing (a clean clone).
npm_install(Dir) ->
    case lists:all(fun(P) -> filelib:is_dir(filename:join([Dir, "node_modules", P])) end,
                   ["playwright-core", "axe-core"]) of
        true ->
            ok;
        false ->
            Out = os:cmd("cd '" ++ Dir ++ "' && npm ci --no-audit --no-fund 2>&1; echo status=$?"),
            ct:log("npm ci: ~ts", [Out]),
            case string:find(Out, "status=0") of
                nomatch -> {error, {npm_ci_failed, Out}};
                _ -> ok
            end
    end.
