%% The Erlang implementation checked against the shared test vectors of
%% test/vectors/ (README.md there says what each kind means and how it is
%% checked): decode == expect, encode round trips, canonical documents and
%% frames byte-exact, invalid input refused with its class, and the
%% transcripts and error answers replayed against a real node over TCP.
%% The vectors are the committed files; nothing here regenerates them.
-module(agent_bridge_vectors_SUITE).

-include_lib("common_test/include/ct.hrl").

-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([index_is_well_formed/1, frames/1, documents/1, invalid/1,
         transcripts_decode/1, transcript_replay/1, errors_replay/1,
         a_changed_vector_is_caught/1]).

-define(V, agent_bridge_vectors).

suite() -> [{timetrap, {minutes, 2}}].

all() ->
    [index_is_well_formed, frames, documents, invalid, transcripts_decode,
     transcript_replay, errors_replay, a_changed_vector_is_caught].

init_per_suite(Config) ->
    Dir = ?V:vectors_dir(),
    {ok, Json} = file:read_file(filename:join(Dir, "vectors.json")),
    {ok, #{<<"version">> := 1, <<"vectors">> := Vectors}} =
        evatar_json:decode(Json, #{max_size => 16#1000000}),
    ok = application:set_env(agent_bridge, listeners, [], [{persistent, true}]),
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    {ok, _} = evatar:create_pairing(<<"vectors">>, #{agent_credential => <<"va-secret">>,
                                                     avatar_credential => <<"avatar-secret">>}),
    %% The transcripts' Welcome carries Heartbeat 500, the value the shared
    %% vectors were written with (not the default, which may change).
    {ok, _} = agent_bridge:start_listener(vectors, #{ip => {127, 0, 0, 1}, port => 0,
                                                     conn => #{heartbeat => 500}}),
    {ok, {_, Port}} = agent_bridge:address(vectors),
    [{dir, Dir}, {vectors, Vectors}, {port, Port} | Config].

end_per_suite(_Config) ->
    ok = agent_bridge:stop_listener(vectors),
    ok = evatar:delete_pairing(<<"vectors">>),
    ok.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% Names unique and well formed, kinds known, every file there, every kind
%% present.
index_is_well_formed(Config) ->
    Vectors = ?config(vectors, Config),
    Names = [maps:get(<<"name">>, V) || V <- Vectors],
    length(Names) =:= length(lists:usort(Names)) orelse ct:fail({duplicate_names, Names}),
    [match = re:run(N, "^[a-z0-9_]+$", [{capture, none}]) || N <- Names],
    Kinds = [<<"frame">>, <<"signal">>, <<"control">>, <<"description">>, <<"transcript">>,
             <<"error">>, <<"invalid">>],
    Present = lists:usort([maps:get(<<"kind">>, V) || V <- Vectors]),
    Present = lists:usort(Kinds),
    Files = lists:append([[F || #{<<"file">> := F} <- [V]] ++
                          [F || #{<<"file">> := F} <- maps:get(<<"steps">>, V, [])] ++
                          [F || #{<<"expect">> := #{<<"document">> := F}} <- [V]]
                          || V <- Vectors]),
    Missing = [F || F <- Files, not filelib:is_regular(path(Config, F))],
    [] = Missing,
    {comment, io_lib:format("~b vectors, ~b files", [length(Vectors), length(Files)])}.

%% 5.1: each frame decodes to its document and nothing else, encodes back
%% to its bytes, and its document is canonical.
frames(Config) ->
    each(Config, <<"frame">>, fun check_frame/2).

%% 5.2: each signal, control and description means what it expects, has
%% its kind, round trips through the encoder, and is byte-exact if canonical.
documents(Config) ->
    N = each(Config, <<"signal">>, fun check_document/2),
    M = each(Config, <<"control">>, fun check_document/2),
    K = each(Config, <<"description">>, fun check_document/2),
    {comment, io_lib:format("~b signals, ~b controls, ~b descriptions", [N, M, K])}.

%% 5.4: each invalid frame or document is refused with its class.
invalid(Config) ->
    each(Config, <<"invalid">>, fun check_invalid/2).

%% 5.5, offline: each transcript step is one frame whose meaning is the
%% step's and whose document the encoder writes back byte for byte.
transcripts_decode(Config) ->
    each(Config, <<"transcript">>, fun check_transcript/2).

%% 5.5, against the suite's node over TCP: each transcript's client steps
%% sent, its server steps read and compared, session ids followed.
transcript_replay(Config) ->
    Port = ?config(port, Config),
    each(Config, <<"transcript">>, fun(C, V) -> replay(C, V, Port) end).

%% 5.6, against the node: each error vector, after its setup, is answered
%% with its error code, and closes the connection or not as recorded.
errors_replay(Config) ->
    Port = ?config(port, Config),
    each(Config, <<"error">>, fun(C, V) -> check_error(C, V, Port) end).

%% The checks are not blind: a vector changed in any of the ways a careless
%% edit or a diverging implementation would change it makes them fail.
a_changed_vector_is_caught(Config) ->
    Vectors = ?config(vectors, Config),
    Find = fun(Name) -> hd([V || #{<<"name">> := N} = V <- Vectors, N =:= Name]) end,
    Fails = fun(Check, V) ->
                    try Check(Config, V) of
                        _ -> ct:fail({not_caught, maps:get(<<"name">>, V)})
                    catch
                        error:_ -> ok
                    end
            end,
    Set = fun(V, Path, Value) -> set_path(V, Path, Value) end,
    Sig = Find(<<"signal_request">>),
    ok = Fails(fun check_document/2, Set(Sig, [<<"expect">>, <<"timestamp">>], 1)),
    ok = Fails(fun check_document/2, Set(Sig, [<<"expect">>, <<"sequence">>], 0)),
    ok = Fails(fun check_document/2, Set(Sig, [<<"expect">>, <<"parameters">>], [])),
    ok = Fails(fun check_document/2, Set(Sig, [<<"canonical">>], false)),
    ok = Fails(fun check_document/2, Set(Find(<<"signal_pretty">>), [<<"canonical">>], true)),
    ok = Fails(fun check_document/2, Set(Find(<<"control_welcome_v1">>),
                                         [<<"expect">>, <<"epoch">>], 1)),
    ok = Fails(fun check_document/2, Set(Find(<<"control_bye">>), [<<"kind">>], <<"signal">>)),
    ok = Fails(fun check_document/2, Set(Find(<<"description_avatar">>),
                                         [<<"expect">>, <<"entity_type">>], <<"Agent">>)),
    Frame = Find(<<"frame_hello">>),
    ok = Fails(fun check_frame/2, Set(Frame, [<<"expect">>, <<"length">>], 187)),
    ok = Fails(fun check_frame/2, Set(Frame, [<<"expect">>, <<"document">>],
                                      <<"documents/frame_welcome.xml">>)),
    ok = Fails(fun check_invalid/2, Set(Find(<<"invalid_doctype">>),
                                        [<<"expect">>, <<"error">>], <<"malformed">>)),
    T = Find(<<"transcript_v1">>),
    [S1 | Rest] = maps:get(<<"steps">>, T),
    ok = Fails(fun check_transcript/2,
               T#{<<"steps">> := [Set(S1, [<<"expect">>, <<"credential">>], <<"x">>) | Rest]}),
    Port = ?config(port, Config),
    ok = Fails(fun(C, V) -> check_error(C, V, Port) end,
               Set(Find(<<"error_bad_credential">>), [<<"expect">>, <<"error">>],
                   <<"UnknownPairing">>)),
    ok = Fails(fun(C, V) -> check_error(C, V, Port) end,
               Set(Find(<<"error_malformed_after_welcome">>), [<<"expect">>, <<"close">>], true)),
    ok.

%% ---------------------------------------------------------------------------
%% The checks of README.md section 5 (each raises on a mismatch)
%% ---------------------------------------------------------------------------

%% 5.1: decoder yields the document and nothing else; encoder yields the
%% bytes; the document is canonical.
check_frame(Config, #{<<"file">> := File,
                      <<"expect">> := #{<<"length">> := Len, <<"document">> := DocFile}}) ->
    Bytes = read(Config, File),
    Doc = read(Config, DocFile),
    {ok, Doc, <<>>} = agent_bridge_frame:decode(Bytes, 1048576),
    Len = byte_size(Doc),
    Bytes = iolist_to_binary(agent_bridge_frame:encode(Doc)),
    {ok, Term} = bil_control:parse_frame(Doc, #{}),
    Doc = ?V:encode(?V:to_json(Term)),
    ok.

%% 5.2: meaning, kind, round trip, and bytes when canonical.
check_document(Config, #{<<"kind">> := Kind, <<"file">> := File, <<"canonical">> := Canonical,
                         <<"expect">> := Expect}) ->
    Bytes = read(Config, File),
    {ok, Term} = bil_control:parse_frame(Bytes, #{}),
    Expect = ?V:to_json(Term),
    Kind = ?V:kind(Expect),
    Encoded = ?V:encode(Expect),
    {ok, Again} = bil_control:parse_frame(Encoded, #{}),
    Expect = ?V:to_json(Again),
    Canonical = (Encoded =:= Bytes),
    ok.

%% 5.4: refused, with the class.
check_invalid(Config, #{<<"file">> := File, <<"expect">> := #{<<"error">> := Class}}) ->
    Bytes = read(Config, File),
    Class = case File of
                <<"frames/", _/binary>> ->
                    case agent_bridge_frame:decode(Bytes, 65536) of
                        {error, empty_frame} -> <<"empty_frame">>;
                        {error, {too_large, _}} -> <<"frame_too_large">>;
                        {more, _} -> <<"truncated_frame">>
                    end;
                <<"documents/", _/binary>> ->
                    {error, #{code := Code}} = bil_control:parse_frame(Bytes, #{}),
                    atom_to_binary(Code)
            end,
    ok.

%% 5.5, offline: every step is one frame whose meaning is the step's and
%% whose document the encoder writes back byte for byte.
check_transcript(Config, #{<<"steps">> := Steps}) ->
    true = length(Steps) > 0,
    [begin
         Bytes = read(Config, File),
         {ok, Doc, <<>>} = agent_bridge_frame:decode(Bytes, 1048576),
         {ok, Term} = bil_control:parse_frame(Doc, #{}),
         Expect = ?V:to_json(Term),
         Doc = ?V:encode(Expect)
     end || #{<<"from">> := From, <<"file">> := File, <<"expect">> := Expect} <- Steps,
            From =:= <<"client">> orelse From =:= <<"server">>],
    ok.

%% 5.5, against the node: client steps sent, server steps read on their
%% connection and compared, session ids followed, heartbeats skipped.
replay(Config, #{<<"steps">> := Steps}, Port) ->
    Final = lists:foldl(fun(Step, St) -> replay_step(Config, Step, Port, St) end,
                        #{conns => #{}, sessions => #{}}, Steps),
    [gen_tcp:close(S) || S <- maps:values(maps:get(conns, Final))],
    ok.

replay_step(Config, #{<<"from">> := <<"client">>, <<"connection">> := Conn, <<"file">> := File,
                      <<"expect">> := Expect}, Port, #{conns := Conns, sessions := Sessions} = St) ->
    S = case Conns of
            #{Conn := S0} -> S0;
            #{} -> ?V:connect(Port)
        end,
    Bytes = case Expect of
                #{<<"control">> := <<"Resume">>, <<"session_id">> := Recorded} ->
                    ?V:frame(Expect#{<<"session_id">> := maps:get(Recorded, Sessions)});
                _ ->
                    read(Config, File)
            end,
    ok = ?V:send_frame(S, Bytes),
    St#{conns := Conns#{Conn => S}};
replay_step(_Config, #{<<"from">> := <<"server">>, <<"connection">> := Conn,
                       <<"expect">> := Expect}, _Port, #{conns := Conns, sessions := Sessions} = St) ->
    Beat = Expect =:= #{<<"control">> => <<"Ack">>, <<"accepted">> => null,
                        <<"received">> => null},
    %% Longer than the pairing's feedback timeout (5 s): transcript_requests
    %% waits for it.
    {ok, Frame} = ?V:recv_frame_skipping(maps:get(Conn, Conns), 15000, Beat),
    {ok, Term} = bil_control:parse_frame(?V:body(Frame), #{}),
    Got = ?V:to_json(Term),
    case {Got, Expect} of
        {#{<<"control">> := <<"Welcome">>, <<"session_id">> := Live},
         #{<<"control">> := <<"Welcome">>, <<"session_id">> := Recorded}} ->
            true = is_session_id(Live),
            Same = Expect#{<<"session_id">> := Live},
            {Got, Conn} = {Same, Conn},
            St#{sessions := Sessions#{Recorded => Live}};
        {#{<<"sender">> := <<"EVATAR">>, <<"id">> := _, <<"timestamp">> := _},
         #{<<"sender">> := <<"EVATAR">>, <<"id">> := Id, <<"timestamp">> := T}} ->
            %% EVATAR's own signals: their id and clock differ from run to
            %% run (test/vectors/README.md section 5.5).
            {Expect, Conn} = {Got#{<<"id">> := Id, <<"timestamp">> := T}, Conn},
            St;
        _ ->
            {Expect, Conn} = {Got, Conn},
            St
    end.

is_session_id(Id) ->
    byte_size(Id) =:= 32 andalso re:run(Id, "^[0-9A-F]+$", [{capture, none}]) =:= match.

%% 5.6, against the node.
check_error(Config, #{<<"file">> := File, <<"setup">> := Setup,
                      <<"expect">> := #{<<"error">> := Code, <<"close">> := Close}}, Port) ->
    {Code, Close} = ?V:error_answer(Port, Setup, read(Config, File)),
    ok.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

%% Runs Check on every vector of Kind; fails with every failing name and
%% its reason, not only the first. Returns how many were checked.
each(Config, Kind, Check) ->
    Vectors = [V || #{<<"kind">> := K} = V <- ?config(vectors, Config), K =:= Kind],
    true = Vectors =/= [],
    Failed = lists:filtermap(
               fun(#{<<"name">> := Name} = V) ->
                       try Check(Config, V) of
                           ok -> false
                       catch
                           Class:Reason:Stack ->
                               {true, {Name, Class, Reason, hd(Stack ++ [none])}}
                       end
               end, Vectors),
    case Failed of
        [] -> length(Vectors);
        _ -> ct:fail({failed_vectors, Failed})
    end.

read(Config, Rel) ->
    {ok, Bin} = file:read_file(path(Config, Rel)),
    Bin.

path(Config, Rel) ->
    true = is_binary(Rel) andalso binary:match(Rel, <<"..">>) =:= nomatch,
    filename:join(?config(dir, Config), binary_to_list(Rel)).

set_path(Map, [Key], Value) -> Map#{Key => Value};
set_path(Map, [Key | Rest], Value) -> Map#{Key => set_path(maps:get(Key, Map), Rest, Value)}.
